//! Generated data kept on disk between runs, keyed by everything that shaped
//! it: a reference solution costs minutes to generate and is the same every
//! time the settings are.
//!
//! A [`Cache`] is a folder and a settings text (every setting the data
//! depends on, written by the scene). An entry is a name and a key (what
//! varies inside one run: a Reynolds number, a seed's draw) and holds named
//! `f64` arrays:
//!
//! - `<name>_<hash>.npz`: the arrays by name (NumPy reads it);
//! - `<name>_<hash>.json`: the settings and the key in full, for a reader and
//!   as a check: an entry whose settings or key differ from the ones asked for
//!   is refused ([`LearnError::Cache`]), never read as if it matched.
//!
//! `<hash>` is the 64-bit FNV-1a hash of the settings and the key, stable
//! across Rust versions and platforms. Changing any setting therefore names
//! other files: the old entries stay until the folder is removed, and nothing
//! outlives the folder the caller chose. Writes go through a temporary file and
//! a rename, so a run stopped mid-write leaves no torn entry, and entries of
//! different keys can be written from several threads at once.
//!
//! ```
//! use diffphys_learn::{cache::Cache, LearnError};
//! use ndarray::{arr1, ArrayD};
//!
//! let dir = std::env::temp_dir().join(format!("diffphys-cache-doc-{}", std::process::id()));
//! let cache = Cache::new(&dir, "grid 32 x 64, dt 0.01")?;
//! let make = || Ok::<_, LearnError>(vec![("u".to_string(), arr1(&[1.0, 2.0]).into_dyn())]);
//! let (first, hit) = cache.get_or_make("reference", "re 100", make)?;
//! assert!(!hit);
//! let (again, hit) = cache.get_or_make("reference", "re 100", || -> Result<_, LearnError> {
//!     unreachable!("read from the cache")
//! })?;
//! assert!(hit);
//! assert_eq!(first, again);
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok::<(), LearnError>(())
//! ```

use std::fs::File;
use std::path::{Path, PathBuf};

use ndarray::{ArrayD, IxDyn, OwnedRepr};
use ndarray_npy::{NpzReader, NpzWriter};
use serde_json::{json, Value};

use crate::{LearnError, Result};

/// Named arrays, in the order they were stored.
pub type Arrays = Vec<(String, ArrayD<f64>)>;

/// FNV-1a, 64 bits: a hash that stays the same across Rust versions.
pub fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn cache_error(path: &Path, message: impl std::fmt::Display) -> LearnError {
    LearnError::Cache {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// A folder of generated arrays keyed by the settings that shaped them (see
/// the [module docs](self)).
#[derive(Debug, Clone, PartialEq)]
pub struct Cache {
    dir: PathBuf,
    settings: String,
}

impl Cache {
    /// The cache in `dir` (created if missing) for data shaped by
    /// `settings`.
    ///
    /// # Errors
    /// [`LearnError::Cache`] if the folder cannot be created.
    pub fn new(dir: impl AsRef<Path>, settings: impl Into<String>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        std::fs::create_dir_all(&dir).map_err(|e| cache_error(&dir, e))?;
        Ok(Cache {
            dir,
            settings: settings.into(),
        })
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The settings text every entry is keyed by.
    pub fn settings(&self) -> &str {
        &self.settings
    }

    /// The path of entry `name` at `key`, without its extension.
    fn stem(&self, name: &str, key: &str) -> PathBuf {
        let hash = fnv1a(&format!("{} {key}", self.settings));
        self.dir.join(format!("{name}_{hash:016x}"))
    }

    /// The arrays of entry `name` at `key`, or `None` if there is none.
    ///
    /// # Errors
    /// [`LearnError::Cache`] if the entry cannot be read, or was written for
    /// other settings or another key.
    pub fn get(&self, name: &str, key: &str) -> Result<Option<Arrays>> {
        let stem = self.stem(name, key);
        let (data, card) = (stem.with_extension("npz"), stem.with_extension("json"));
        if !data.exists() {
            return Ok(None);
        }
        let text = std::fs::read_to_string(&card).map_err(|e| cache_error(&card, e))?;
        let found: Value = serde_json::from_str(&text).map_err(|e| cache_error(&card, e))?;
        let expected = self.card(name, key);
        if found != expected {
            return Err(cache_error(
                &card,
                format!("holds {found}, not the entry asked for ({expected})"),
            ));
        }
        let file = File::open(&data).map_err(|e| cache_error(&data, e))?;
        let mut npz = NpzReader::new(file).map_err(|e| cache_error(&data, e))?;
        let names = npz.names().map_err(|e| cache_error(&data, e))?;
        let mut arrays = Vec::with_capacity(names.len());
        for file_name in names {
            let a = npz
                .by_name::<OwnedRepr<f64>, IxDyn>(&file_name)
                .map_err(|e| cache_error(&data, e))?;
            let name = file_name.strip_suffix(".npy").unwrap_or(&file_name);
            arrays.push((name.to_string(), a));
        }
        Ok(Some(arrays))
    }

    /// Stores `arrays` as entry `name` at `key` (replacing it).
    ///
    /// # Errors
    /// [`LearnError::Cache`] if a file cannot be written, or two arrays share
    /// a name.
    pub fn put(&self, name: &str, key: &str, arrays: &Arrays) -> Result<()> {
        let stem = self.stem(name, key);
        let (data, card) = (stem.with_extension("npz"), stem.with_extension("json"));
        for (i, (a, _)) in arrays.iter().enumerate() {
            if arrays[..i].iter().any(|(b, _)| b == a) {
                return Err(cache_error(&data, format!("two arrays named {a:?}")));
            }
        }
        let text = serde_json::to_string_pretty(&self.card(name, key))
            .map_err(|e| cache_error(&card, e))?;
        write_atomically(&card, |path| {
            std::fs::write(path, text + "\n").map_err(|e| cache_error(path, e))
        })?;
        write_atomically(&data, |path| {
            let file = File::create(path).map_err(|e| cache_error(path, e))?;
            let mut npz = NpzWriter::new(file);
            for (n, a) in arrays {
                npz.add_array(n.as_str(), a)
                    .map_err(|e| cache_error(path, e))?;
            }
            npz.finish().map_err(|e| cache_error(path, e))?;
            Ok(())
        })
    }

    /// The entry `name` at `key` if it is stored, else what `make` returns,
    /// stored; and whether it was found.
    ///
    /// # Errors
    /// As [`Cache::get`] and [`Cache::put`]; whatever `make` returns (nothing
    /// is stored then).
    pub fn get_or_make<E: From<LearnError>>(
        &self,
        name: &str,
        key: &str,
        make: impl FnOnce() -> std::result::Result<Arrays, E>,
    ) -> std::result::Result<(Arrays, bool), E> {
        if let Some(arrays) = self.get(name, key)? {
            return Ok((arrays, true));
        }
        let arrays = make()?;
        self.put(name, key, &arrays)?;
        Ok((arrays, false))
    }

    fn card(&self, name: &str, key: &str) -> Value {
        json!({"name": name, "key": key, "settings": self.settings})
    }
}

/// Writes `path` through a temporary file beside it and a rename.
fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    write(&tmp)?;
    std::fs::rename(&tmp, path).map_err(|e| cache_error(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{arr2, Array};

    fn temp(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("diffphys-cache-{name}-{}", std::process::id()));
        std::fs::remove_dir_all(&dir).ok();
        dir
    }

    #[test]
    fn entries_round_trip_to_the_bit_and_keys_and_settings_name_other_files() {
        let dir = temp("round-trip");
        let cache = Cache::new(&dir, "a").unwrap();
        let awkward = Array::from_shape_fn(vec![3, 2, 5], |i| {
            (i[0] as f64 + 0.1).powf(-7.3) * f64::from(i[1] as u8).exp() - i[2] as f64 / 3.0
        });
        let arrays = vec![
            ("u".to_string(), awkward.clone()),
            (
                "v".to_string(),
                arr2(&[[f64::MIN_POSITIVE, -0.0]]).into_dyn(),
            ),
        ];
        assert!(cache.get("ref", "k1").unwrap().is_none());
        cache.put("ref", "k1", &arrays).unwrap();
        let back = cache.get("ref", "k1").unwrap().unwrap();
        assert_eq!(back.len(), 2);
        for ((n, a), (m, b)) in arrays.iter().zip(&back) {
            assert_eq!(n, m);
            assert_eq!(a.shape(), b.shape());
            assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
        }
        assert!(cache.get("ref", "k2").unwrap().is_none());
        assert!(Cache::new(&dir, "b")
            .unwrap()
            .get("ref", "k1")
            .unwrap()
            .is_none());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn an_entry_for_other_settings_is_refused_and_make_errors_store_nothing() {
        let dir = temp("refuse");
        let cache = Cache::new(&dir, "a").unwrap();
        let one = vec![("x".to_string(), arr2(&[[1.0]]).into_dyn())];
        cache.put("ref", "k", &one).unwrap();
        // A card that does not match its file name (a copied or edited file).
        let card = cache.stem("ref", "k").with_extension("json");
        std::fs::write(&card, r#"{"name": "ref", "key": "k", "settings": "other"}"#).unwrap();
        assert!(matches!(
            cache.get("ref", "k"),
            Err(LearnError::Cache { .. })
        ));
        let failed = cache.get_or_make("new", "k", || {
            Err::<Arrays, _>(LearnError::invalid("data", "the solver diverged"))
        });
        assert!(matches!(failed, Err(LearnError::Invalid { .. })));
        assert!(cache.get("new", "k").unwrap().is_none());
        let twice = vec![one[0].clone(), one[0].clone()];
        assert!(matches!(
            cache.put("dup", "k", &twice),
            Err(LearnError::Cache { .. })
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
}
