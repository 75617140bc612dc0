//! Fields and gradients out to NumPy: `.npy` files (one array each, written with
//! `ndarray-npy`) under a folder, and an `index.json` naming every file, its
//! shape, dtype and meaning.
//!
//! ```no_run
//! use diffphys_report::npy::NpyWriter;
//! use ndarray::ArrayD;
//!
//! let mut npy = NpyWriter::new("out/scene/npy")?;
//! let field = ArrayD::<f64>::zeros(ndarray::IxDyn(&[64, 64]));
//! npy.write("pressure", field.view(), "the pressure after the last step")?;
//! npy.finish()?; // writes out/scene/npy/index.json
//! # Ok::<(), diffphys_report::ReportError>(())
//! ```
//!
//! In Python: `np.load("out/scene/npy/pressure.npy")`.

use std::path::{Path, PathBuf};

use diffphys_tape::Real;
use ndarray::ArrayViewD;
use ndarray_npy::{write_npy, WritableElement};
use serde::{Deserialize, Serialize};

use crate::{ReportError, Result};

/// One line of `index.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NpyEntry {
    /// The array's name (its file is `{name}.npy`).
    pub name: String,
    /// The file name, relative to the index.
    pub file: String,
    /// The array's shape.
    pub shape: Vec<usize>,
    /// `"float32"` or `"float64"` (NumPy's names).
    pub dtype: String,
    /// What the array holds.
    pub meaning: String,
}

/// Writes arrays as `.npy` files into one folder and indexes them.
#[derive(Debug)]
pub struct NpyWriter {
    dir: PathBuf,
    entries: Vec<NpyEntry>,
}

fn io_error(path: &Path, source: std::io::Error) -> ReportError {
    ReportError::Io {
        path: path.display().to_string(),
        source,
    }
}

impl NpyWriter {
    /// A writer into `dir`, created if missing.
    ///
    /// # Errors
    /// [`ReportError::Io`] if the folder cannot be created.
    pub fn new(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        std::fs::create_dir_all(&dir).map_err(|e| io_error(&dir, e))?;
        Ok(NpyWriter {
            dir,
            entries: Vec::new(),
        })
    }

    /// The folder written into.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Writes `array` as `{name}.npy` and records it in the index.
    ///
    /// # Errors
    /// [`ReportError::InvalidArgument`] for a name that is empty, taken, or not
    /// a plain file name; [`ReportError::Io`] if writing fails.
    pub fn write<T: Real + WritableElement>(
        &mut self,
        name: &str,
        array: ArrayViewD<'_, T>,
        meaning: &str,
    ) -> Result<PathBuf> {
        let plain = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
        if !plain || self.entries.iter().any(|e| e.name == name) {
            return Err(ReportError::InvalidArgument(format!(
                "npy array name {name:?}: names must be unique and use only letters, digits, '_', '-' and '.'"
            )));
        }
        let file = format!("{name}.npy");
        let path = self.dir.join(&file);
        write_npy(&path, &array)
            .map_err(|e| io_error(&path, std::io::Error::other(e.to_string())))?;
        self.entries.push(NpyEntry {
            name: name.to_string(),
            file,
            shape: array.shape().to_vec(),
            dtype: if T::NAME == "f32" {
                "float32"
            } else {
                "float64"
            }
            .to_string(),
            meaning: meaning.to_string(),
        });
        Ok(path)
    }

    /// The entries written so far.
    pub fn entries(&self) -> &[NpyEntry] {
        &self.entries
    }

    /// Writes `index.json` and returns its path.
    ///
    /// # Errors
    /// [`ReportError::Io`] or [`ReportError::Json`].
    pub fn finish(self) -> Result<PathBuf> {
        let path = self.dir.join("index.json");
        let text = serde_json::to_string_pretty(&self.entries)?;
        std::fs::write(&path, text).map_err(|e| io_error(&path, e))?;
        Ok(path)
    }
}
