//! Saved models: the parameters of a trained network plus everything that
//! shaped them, so that an hour of training outlives its process and a model
//! can be evaluated later, anywhere, without training again.
//!
//! A saved model is a directory of two files:
//!
//! - `params.npz`: every parameter by name ([`Params::save`]; NumPy reads it,
//!   values round-trip bit for bit);
//! - `model.json`: its [`ModelCard`]: the `kind` of model, the `settings` a
//!   loader must match (the scene, the network's architecture, its arithmetic)
//!   and the `provenance` that is recorded but never compared (budget, seeds,
//!   learning rate, validation score, the source commit).
//!
//! Loading checks the card against the settings of the scene it is loaded
//! into, field by field, and refuses a model whose settings differ with
//! [`LearnError::SettingsMismatch`] naming the field: a corrector trained on a
//! 16 × 32 grid is never silently run on a 32 × 64 one.
//!
//! ```
//! use diffphys_learn::saved::{ModelCard, SavedModel};
//! use diffphys_learn::LearnError;
//! use diffphys_nn::Params;
//! use diffphys_tape::ArrayD;
//!
//! let mut params = Params::<f64>::new();
//! params.add("w", ArrayD::from_elem(vec![2, 2], 0.25))?;
//! let card = ModelCard::new("toy")
//!     .setting("grid", [16, 32])
//!     .provenance("train_seed", 3);
//! let dir = std::env::temp_dir().join(format!("diffphys-saved-doc-{}", std::process::id()));
//! SavedModel::save(&dir, &params, &card)?;
//!
//! // Loaded into the same scene: the same parameters, to the bit.
//! let mut loaded = Params::<f64>::new();
//! loaded.add("w", ArrayD::zeros(vec![2, 2]))?;
//! SavedModel::load(&dir, &ModelCard::new("toy").setting("grid", [16, 32]), &mut loaded)?;
//! assert_eq!(loaded.values(), params.values());
//!
//! // Into another scene: refused, naming the field.
//! let other = ModelCard::new("toy").setting("grid", [32, 64]);
//! let err = SavedModel::load(&dir, &other, &mut loaded).unwrap_err();
//! assert!(matches!(err, LearnError::SettingsMismatch { ref field, .. } if field == "grid"));
//! # std::fs::remove_dir_all(&dir).ok();
//! # Ok::<(), LearnError>(())
//! ```

use std::path::{Path, PathBuf};

use diffphys_nn::Params;
use serde::Serialize;
use serde_json::{json, Map, Value};

use crate::{LearnError, Result};

/// The parameters' file inside a model directory.
pub const PARAMS_FILE: &str = "params.npz";
/// The card's file inside a model directory.
pub const CARD_FILE: &str = "model.json";
/// The version of the card's layout this crate writes and reads.
pub const FORMAT: u64 = 1;

/// What shaped a model: the settings a loader must match and the provenance
/// that is only recorded.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ModelCard {
    /// What the model is (`"wake_flow corrector"`): a card of another kind is
    /// refused.
    pub kind: String,
    /// Compared field by field on loading: the scene (grid, time step, body,
    /// schemes) and the network (architecture, arithmetic).
    pub settings: Map<String, Value>,
    /// Recorded, never compared: budget, seeds, learning rate, validation
    /// score, timings.
    pub provenance: Map<String, Value>,
}

impl ModelCard {
    /// An empty card of `kind`.
    pub fn new(kind: impl Into<String>) -> Self {
        ModelCard {
            kind: kind.into(),
            ..ModelCard::default()
        }
    }

    /// Adds a setting a loader must match.
    ///
    /// # Panics
    /// If `value` cannot be represented as JSON (a map with non-string keys);
    /// numbers, strings, arrays and plain structs always can.
    pub fn setting(mut self, key: &str, value: impl Serialize) -> Self {
        self.settings.insert(key.into(), to_value(value));
        self
    }

    /// Adds a field of provenance (recorded, never compared).
    ///
    /// # Panics
    /// As [`ModelCard::setting`].
    pub fn provenance(mut self, key: &str, value: impl Serialize) -> Self {
        self.provenance.insert(key.into(), to_value(value));
        self
    }

    /// Checks that a saved card (`self`) fits the scene that `expected`
    /// describes: the same kind and the same value for every setting, none
    /// missing and none extra. Numbers are compared as they read back from
    /// JSON, so a value that went through a file compares equal to itself.
    ///
    /// # Errors
    /// [`LearnError::SettingsMismatch`] naming the first field (in order of
    /// name) that differs, is missing (`saved` is `null`) or is extra
    /// (`expected` is `null`); `kind` for another kind of model.
    pub fn check(&self, expected: &ModelCard) -> Result<()> {
        if self.kind != expected.kind {
            return Err(mismatch("kind", &json!(self.kind), &json!(expected.kind)));
        }
        let mut fields: Vec<&String> = self
            .settings
            .keys()
            .chain(expected.settings.keys())
            .collect();
        fields.sort();
        fields.dedup();
        for field in fields {
            let saved = self
                .settings
                .get(field)
                .map(through_json)
                .unwrap_or(Value::Null);
            let wanted = expected
                .settings
                .get(field)
                .map(through_json)
                .unwrap_or(Value::Null);
            if saved != wanted {
                return Err(mismatch(field, &saved, &wanted));
            }
        }
        Ok(())
    }
}

/// A model directory opened: its card and where it lives.
#[derive(Debug, Clone, PartialEq)]
pub struct SavedModel {
    /// The directory.
    pub dir: PathBuf,
    /// Its card.
    pub card: ModelCard,
    /// The source commit it was trained at, where it was known.
    pub commit: Option<String>,
}

impl SavedModel {
    /// Writes `params` and `card` into `dir` (created if missing; the two
    /// files are replaced). The source commit is recorded from the
    /// `DIFFPHYS_COMMIT` environment variable or, failing that, from
    /// `git describe --always --dirty` in the working directory (a commit hash,
    /// `-dirty` where the tree had changes), where either answers.
    ///
    /// # Errors
    /// [`LearnError::Model`] if the directory or a file cannot be written;
    /// [`diffphys_nn::NnError::NonFiniteParameter`] (through
    /// [`LearnError::Nn`]) if a parameter is NaN or infinite: nothing is saved
    /// then.
    pub fn save(
        dir: impl AsRef<Path>,
        params: &Params<f64>,
        card: &ModelCard,
    ) -> Result<SavedModel> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| model_error(dir, e))?;
        params.save(dir.join(PARAMS_FILE))?;
        let commit = source_commit();
        let text = serde_json::to_string_pretty(&json!({
            "format": FORMAT,
            "kind": card.kind,
            "settings": card.settings,
            "provenance": card.provenance,
            "parameters": params.count(),
            "commit": commit,
        }))
        .map_err(|e| model_error(dir, e))?;
        let card_path = dir.join(CARD_FILE);
        std::fs::write(&card_path, text + "\n").map_err(|e| model_error(&card_path, e))?;
        Ok(SavedModel {
            dir: dir.to_path_buf(),
            card: card.clone(),
            commit,
        })
    }

    /// Opens a model directory: reads and parses its card (the parameters are
    /// read by [`SavedModel::load_params`]).
    ///
    /// # Errors
    /// [`LearnError::Model`] if the card is missing, is not JSON, lacks a
    /// field or has another format version.
    pub fn open(dir: impl AsRef<Path>) -> Result<SavedModel> {
        let dir = dir.as_ref();
        let path = dir.join(CARD_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| model_error(&path, e))?;
        let value: Value = serde_json::from_str(&text).map_err(|e| model_error(&path, e))?;
        let field = |name: &str| {
            value
                .get(name)
                .ok_or_else(|| model_error(&path, format!("the card has no {name:?} field")))
        };
        let format = field("format")?.as_u64();
        if format != Some(FORMAT) {
            return Err(model_error(
                &path,
                format!("card format {format:?}; this version reads format {FORMAT}"),
            ));
        }
        let object = |name: &str| -> Result<Map<String, Value>> {
            field(name)?
                .as_object()
                .cloned()
                .ok_or_else(|| model_error(&path, format!("{name:?} is not an object")))
        };
        let card = ModelCard {
            kind: field("kind")?
                .as_str()
                .ok_or_else(|| model_error(&path, "\"kind\" is not a string"))?
                .to_string(),
            settings: object("settings")?,
            provenance: object("provenance")?,
        };
        Ok(SavedModel {
            dir: dir.to_path_buf(),
            card,
            commit: value
                .get("commit")
                .and_then(Value::as_str)
                .map(str::to_string),
        })
    }

    /// Replaces `params` (a model built for the scene, with the names and
    /// shapes the saved one has) by the saved values.
    ///
    /// # Errors
    /// As [`Params::load`] (through [`LearnError::Nn`]): a missing file,
    /// other names or shapes, a non-finite value; `params` is unchanged then.
    pub fn load_params(&self, params: &mut Params<f64>) -> Result<()> {
        params.load(self.dir.join(PARAMS_FILE))?;
        Ok(())
    }

    /// Opens `dir`, checks its card against `expected` and loads the
    /// parameters into `params`.
    ///
    /// # Errors
    /// As [`SavedModel::open`], [`ModelCard::check`] (nothing is loaded on a
    /// mismatch) and [`SavedModel::load_params`].
    pub fn load(
        dir: impl AsRef<Path>,
        expected: &ModelCard,
        params: &mut Params<f64>,
    ) -> Result<SavedModel> {
        let saved = SavedModel::open(dir)?;
        saved.card.check(expected)?;
        saved.load_params(params)?;
        Ok(saved)
    }
}

fn to_value(value: impl Serialize) -> Value {
    serde_json::to_value(value).expect("a setting is representable as JSON")
}

/// `value` as it reads back from its JSON text (floats parse back to the
/// value the file holds, whichever way the parser rounds).
fn through_json(value: &Value) -> Value {
    serde_json::to_string(value)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or(Value::Null)
}

fn mismatch(field: &str, saved: &Value, expected: &Value) -> LearnError {
    LearnError::SettingsMismatch {
        field: field.to_string(),
        saved: saved.to_string(),
        expected: expected.to_string(),
    }
}

fn model_error(path: &Path, e: impl std::fmt::Display) -> LearnError {
    LearnError::Model {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// The commit the running code was built from, where it can be told.
fn source_commit() -> Option<String> {
    if let Ok(commit) = std::env::var("DIFFPHYS_COMMIT") {
        return Some(commit);
    }
    let out = std::process::Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=40"])
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let commit = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (out.status.success() && !commit.is_empty()).then_some(commit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffphys_tape::ArrayD;

    fn dir(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("diffphys-saved-{name}-{}", std::process::id()))
    }

    fn params(value: f64) -> Params<f64> {
        let mut p = Params::new();
        p.add("a", ArrayD::from_elem(vec![3], value)).unwrap();
        p.add(
            "b",
            ArrayD::from_shape_fn(vec![2, 2], |i| value * (i[0] + 2 * i[1]) as f64 / 3.0),
        )
        .unwrap();
        p
    }

    fn card() -> ModelCard {
        ModelCard::new("test")
            .setting("grid", [16, 32])
            .setting("dt", 0.1 + 0.2)
            .setting("body", "inscribed")
            .provenance("seed", 7)
    }

    #[test]
    fn a_saved_model_reloads_to_the_bit_and_keeps_its_card() {
        let d = dir("roundtrip");
        let saved = SavedModel::save(&d, &params(0.1), &card()).unwrap();
        let mut p = params(0.0);
        let loaded = SavedModel::load(&d, &card(), &mut p).unwrap();
        assert_eq!(p.values(), params(0.1).values());
        assert_eq!(loaded.card.provenance, saved.card.provenance);
        assert_eq!(loaded.card.kind, "test");
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn another_setting_is_refused_naming_the_field_and_nothing_is_loaded() {
        let d = dir("mismatch");
        SavedModel::save(&d, &params(0.1), &card()).unwrap();
        let cases = [
            (card().setting("dt", 0.3), "dt"),
            (card().setting("body", "staircase"), "body"),
            (card().setting("width", 16), "width"),
            (
                ModelCard {
                    kind: "other".into(),
                    ..card()
                },
                "kind",
            ),
        ];
        for (expected, field) in cases {
            let mut p = params(0.0);
            match SavedModel::load(&d, &expected, &mut p) {
                Err(LearnError::SettingsMismatch { field: f, .. }) => assert_eq!(f, field),
                other => panic!("expected a mismatch on {field}, got {other:?}"),
            }
            assert_eq!(p.values(), params(0.0).values(), "{field}: nothing loaded");
        }
        // A setting the scene no longer has is refused too.
        let mut fewer = card();
        fewer.settings.remove("body");
        let err = SavedModel::load(&d, &fewer, &mut params(0.0)).unwrap_err();
        assert!(matches!(err, LearnError::SettingsMismatch { ref field, .. } if field == "body"));
        // Provenance is never compared.
        let other_seed = card().provenance("seed", 8);
        SavedModel::load(&d, &other_seed, &mut params(0.0)).unwrap();
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn a_missing_or_broken_card_is_a_typed_error() {
        let d = dir("broken");
        assert!(matches!(
            SavedModel::open(&d),
            Err(LearnError::Model { .. })
        ));
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(CARD_FILE), "{\"format\": 99}").unwrap();
        let err = SavedModel::open(&d).unwrap_err();
        assert!(err.to_string().contains("format"), "{err}");
        std::fs::write(d.join(CARD_FILE), "not json").unwrap();
        assert!(matches!(
            SavedModel::open(&d),
            Err(LearnError::Model { .. })
        ));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn parameters_of_another_shape_are_refused() {
        let d = dir("shape");
        SavedModel::save(&d, &params(0.1), &card()).unwrap();
        let mut p = Params::new();
        p.add("a", ArrayD::zeros(vec![4])).unwrap();
        p.add("b", ArrayD::zeros(vec![2, 2])).unwrap();
        assert!(matches!(
            SavedModel::load(&d, &card(), &mut p),
            Err(LearnError::Nn(_))
        ));
        std::fs::remove_dir_all(&d).ok();
    }
}
