//! How often a held-out split was read, across runs.
//!
//! [`HeldOut::readings`](crate::HeldOut::readings) counts the readings of one
//! process. A held-out figure a developer has read is spent, though, whichever
//! run read it: a default changed after reading it was chosen on it. A
//! [`Ledger`] is a file in the study's output folder (beside the data cache)
//! to which every run appends its readings of each split, so that a report can
//! say how often this split was read by this configuration and by any.
//!
//! The file, `held_out_ledger.json`, is a JSON array, one object per run and
//! split: the split's text and hash (what identifies the data: the held-out
//! conditions, the data seed, the generator's settings), the configuration's
//! text and hash (everything that shaped the models read on it), and the
//! counts of that run. It is only ever appended to; remove it to start a new
//! count (and say so).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cache::fnv1a;
use crate::{LearnError, Result};

/// The ledger's file name.
pub const LEDGER_FILE: &str = "held_out_ledger.json";

/// One run's readings of one held-out split.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Reading {
    /// The split's hash (FNV-1a of its text, hexadecimal).
    pub split_hash: String,
    /// What identifies the split's data.
    pub split: String,
    /// The configuration's hash (FNV-1a of its text, hexadecimal).
    pub configuration_hash: String,
    /// Everything that shaped the models read on it.
    pub configuration: String,
    /// Trained models evaluated on it in that run.
    pub trained_models: usize,
    /// Baseline readings (models without trained parameters) in that run.
    pub baseline_readings: usize,
}

/// The count of a split's readings after one more, over every run the
/// ledger holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Tally {
    /// Runs of this configuration that read the split (this one included).
    pub runs_of_this_configuration: usize,
    /// Runs of any configuration that read the split.
    pub runs_of_any_configuration: usize,
    /// Distinct configurations that read it.
    pub configurations: usize,
    /// Trained models evaluated on it, over every run.
    pub trained_models: usize,
}

fn ledger_error(path: &Path, message: impl std::fmt::Display) -> LearnError {
    LearnError::Cache {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The held-out ledger of an output folder: `held_out_ledger.json`, one
/// entry per run and split, only ever appended to (see [`Ledger::record`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ledger {
    path: PathBuf,
}

impl Ledger {
    /// The ledger in `dir` (created if missing; the file is created by the
    /// first [`Ledger::record`]).
    ///
    /// # Errors
    /// [`LearnError::Cache`] if the folder cannot be created.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| ledger_error(dir, e))?;
        Ok(Ledger {
            path: dir.join(LEDGER_FILE),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Every reading recorded so far, oldest first.
    ///
    /// # Errors
    /// [`LearnError::Cache`] if the file exists but cannot be read or parsed.
    pub fn readings(&self) -> Result<Vec<Reading>> {
        match std::fs::read_to_string(&self.path) {
            Ok(text) => serde_json::from_str(&text).map_err(|e| ledger_error(&self.path, e)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
            Err(e) => Err(ledger_error(&self.path, e)),
        }
    }

    /// Appends this run's reading of `split` by `configuration` (`(trained
    /// models, baseline readings)`, as [`HeldOut::readings`](crate::HeldOut::readings)
    /// gives them) and returns the split's tally.
    ///
    /// # Errors
    /// As [`Ledger::readings`]; [`LearnError::Cache`] if the file cannot be
    /// written; [`LearnError::Invalid`] for a reading of nothing (a run that
    /// read no split has nothing to record).
    pub fn record(
        &self,
        split: &str,
        configuration: &str,
        (trained_models, baseline_readings): (usize, usize),
    ) -> Result<Tally> {
        if trained_models + baseline_readings == 0 {
            return Err(LearnError::invalid(
                "held-out ledger",
                "a reading of no model and no baseline",
            ));
        }
        let mut all = self.readings()?;
        let reading = Reading {
            split_hash: format!("{:016x}", fnv1a(split)),
            split: split.to_string(),
            configuration_hash: format!("{:016x}", fnv1a(configuration)),
            configuration: configuration.to_string(),
            trained_models,
            baseline_readings,
        };
        all.push(reading.clone());
        let text = serde_json::to_string_pretty(&all).map_err(|e| ledger_error(&self.path, e))?;
        let mut tmp = self.path.as_os_str().to_owned();
        tmp.push(".tmp");
        let tmp = PathBuf::from(tmp);
        std::fs::write(&tmp, text + "\n").map_err(|e| ledger_error(&tmp, e))?;
        std::fs::rename(&tmp, &self.path).map_err(|e| ledger_error(&self.path, e))?;
        let of_split: Vec<&Reading> = all
            .iter()
            .filter(|r| r.split_hash == reading.split_hash)
            .collect();
        let mut configurations: Vec<&str> = of_split
            .iter()
            .map(|r| r.configuration_hash.as_str())
            .collect();
        configurations.sort_unstable();
        configurations.dedup();
        Ok(Tally {
            runs_of_this_configuration: of_split
                .iter()
                .filter(|r| r.configuration_hash == reading.configuration_hash)
                .count(),
            runs_of_any_configuration: of_split.len(),
            configurations: configurations.len(),
            trained_models: of_split.iter().map(|r| r.trained_models).sum(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readings_add_up_per_split_and_configuration_across_opens() {
        let dir = std::env::temp_dir().join(format!("diffphys-ledger-{}", std::process::id()));
        std::fs::remove_dir_all(&dir).ok();
        let ledger = Ledger::open(&dir).unwrap();
        assert!(ledger.readings().unwrap().is_empty());
        let first = ledger
            .record("re 71, seed 1", "budget 100", (8, 3))
            .unwrap();
        assert_eq!(first.runs_of_this_configuration, 1);
        assert_eq!(first.configurations, 1);
        ledger
            .record("re 71, seed 2", "budget 100", (8, 3))
            .unwrap();
        // A new run (a new process) opens the same file.
        let again = Ledger::open(&dir).unwrap();
        let third = again.record("re 71, seed 1", "budget 200", (4, 1)).unwrap();
        assert_eq!(third.runs_of_this_configuration, 1);
        assert_eq!(third.runs_of_any_configuration, 2);
        assert_eq!(third.configurations, 2);
        assert_eq!(third.trained_models, 12);
        let fourth = again.record("re 71, seed 1", "budget 100", (8, 3)).unwrap();
        assert_eq!(fourth.runs_of_this_configuration, 2);
        assert_eq!(again.readings().unwrap().len(), 4);
        assert!(matches!(
            again.record("re 71, seed 1", "budget 100", (0, 0)),
            Err(LearnError::Invalid { .. })
        ));
        std::fs::write(again.path(), "not json").unwrap();
        assert!(matches!(again.readings(), Err(LearnError::Cache { .. })));
        std::fs::remove_dir_all(&dir).ok();
    }
}
