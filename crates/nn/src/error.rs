//! The one error type of the network crate.

use std::path::PathBuf;

use diffphys_tape::TapeError;
use thiserror::Error;

/// Everything that can go wrong while building, training, saving or loading a
/// network. Layer shape errors come from the tape as [`TapeError::ShapeMismatch`]
/// naming the layer; this enum adds what the tape does not know about.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum NnError {
    /// Recording or sweeping the tape failed (a layer's input shape, a non-finite
    /// value in an op, …).
    #[error(transparent)]
    Tape(#[from] TapeError),
    /// Two parameters were given the same name.
    #[error("parameter {name:?} is already defined")]
    DuplicateName {
        /// The name.
        name: String,
    },
    /// A layer or model was configured with values that cannot work.
    #[error("invalid configuration of {layer}: {message}")]
    Config {
        /// The layer or model.
        layer: String,
        /// What is wrong.
        message: String,
    },
    /// Reading or writing a parameter file failed.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What failed.
        message: String,
    },
    /// A parameter file does not fit the model; the model was left untouched.
    #[error("{path} does not fit the model: {message}")]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// Which names or shapes differ.
        message: String,
    },
    /// A parameter holds NaN or infinity (refused on save and on load).
    #[error("parameter {name:?} has {count} non-finite entries")]
    NonFiniteParameter {
        /// The parameter.
        name: String,
        /// How many entries are non-finite.
        count: usize,
    },
    /// Training produced a non-finite loss; training stops there.
    #[error("non-finite loss {loss} at training step {step}")]
    NonFiniteLoss {
        /// The training step (0-based).
        step: usize,
        /// The loss value.
        loss: f64,
    },
}

/// Result alias of the network crate.
pub type Result<T, E = NnError> = std::result::Result<T, E>;
