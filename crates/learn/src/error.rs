//! The one error type of the learning crate.

use diffphys_nn::NnError;
use diffphys_ops::cg::CgError;
use diffphys_ops::OpsError;
use diffphys_tape::TapeError;
use thiserror::Error;

use crate::split::Split;

/// Everything that can go wrong while building, training, selecting or
/// evaluating a model. Bad input (a zero budget, an empty split, a corrector of
/// the wrong shape) is one of these, never a panic and never an untrained model.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum LearnError {
    /// Recording or sweeping the tape failed.
    #[error(transparent)]
    Tape(#[from] TapeError),
    /// A network failed (a non-finite loss, a bad configuration, …).
    #[error(transparent)]
    Nn(#[from] NnError),
    /// An operator failed.
    #[error(transparent)]
    Ops(#[from] OpsError),
    /// Conjugate gradient failed.
    #[error(transparent)]
    Cg(#[from] CgError),
    /// A training budget of zero iterations: the model would leave untrained.
    #[error("{trainer}: a budget of 0 training iterations would leave the model untrained")]
    ZeroIterations {
        /// The trainer.
        trainer: &'static str,
    },
    /// An unroll of zero steps (solver in the loop, or CG iterations as virtual time).
    #[error("{what}: an unroll of 0 steps has no loss to train on")]
    ZeroUnroll {
        /// What was unrolled.
        what: &'static str,
    },
    /// A split without samples.
    #[error("the {split} split is empty ({context})")]
    EmptySplit {
        /// The split.
        split: Split,
        /// Where it was needed.
        context: String,
    },
    /// The corrector's output does not have the state's shape: one correction
    /// per physical field, each of its field's shape.
    #[error("the corrector's output for field {field} has shape {correction:?} but the field has shape {state:?}")]
    CorrectorShape {
        /// The field.
        field: usize,
        /// The field's shape.
        state: Vec<usize>,
        /// The correction's shape.
        correction: Vec<usize>,
    },
    /// The corrector gave another number of corrections than the state has
    /// physical fields.
    #[error("the corrector gave {got} corrections for a state of {expected} physical fields")]
    CorrectorFields {
        /// The physical fields.
        expected: usize,
        /// The corrections.
        got: usize,
    },
    /// A budget that cannot be shared equally (an unroll longer than the network
    /// evaluations per iteration, or not dividing them).
    #[error("budget: {message}")]
    Budget {
        /// What is wrong.
        message: String,
    },
    /// The same trained model was evaluated on the held-out split a second time.
    #[error("model {model} ({label}) was already evaluated on the held-out split; it is read once per trained model")]
    HeldOutReused {
        /// The model's id.
        model: u64,
        /// Its label.
        label: String,
    },
    /// Model selection was given no candidates, or only non-finite scores.
    #[error("model selection: {message}")]
    Selection {
        /// What is wrong.
        message: String,
    },
    /// A saved model whose settings differ from the scene it is loaded into.
    #[error("the saved model's {field} is {saved}, the scene's is {expected}: it was trained for another setting")]
    SettingsMismatch {
        /// The setting (`kind` for another kind of model).
        field: String,
        /// Its value in the saved model (JSON; `null` if it has none).
        saved: String,
        /// Its value in the scene (JSON; `null` if the scene has none).
        expected: String,
    },
    /// A model directory that cannot be written or read.
    #[error("saved model {}: {message}", path.display())]
    Model {
        /// The file or directory.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A cache entry that cannot be written or read, or was written for
    /// other settings.
    #[error("cache {}: {message}", path.display())]
    Cache {
        /// The file or folder.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
    /// A variant name that is not one of `src`, `non`, `noise`, `solK`.
    #[error("unknown variant {name:?}: choose from src, non, noise, solK (sol4, sol16, ...)")]
    UnknownVariant {
        /// What was asked for.
        name: String,
    },
    /// A chart or a file of a report could not be written.
    #[error(transparent)]
    Report(#[from] diffphys_report::ReportError),
    /// Any other invalid argument.
    #[error("invalid {what}: {message}")]
    Invalid {
        /// The argument.
        what: &'static str,
        /// What is wrong.
        message: String,
    },
}

impl LearnError {
    pub(crate) fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        LearnError::Invalid {
            what,
            message: message.into(),
        }
    }
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, LearnError>;
