//! The one error type of the flow crate.

use diffphys_ops::cg::CgError;
use diffphys_ops::OpsError;
use diffphys_tape::{ErrorKind, TapeError};
use thiserror::Error;

/// Everything a scene or a step can reject or fail at. Each names the piece of
/// the step (`advection`, `pressure solve`, …) and the quantity concerned.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum FlowError {
    /// The scene description cannot be built: a viscosity ≤ 0, an obstacle
    /// that does not fit or covers the inflow, inconsistent sides, …
    #[error("invalid scene ({what}): {message}")]
    InvalidScene {
        /// The quantity at fault (`viscosity`, `obstacle`, `sides`, …).
        what: String,
        /// What is wrong.
        message: String,
    },
    /// An array of the wrong shape.
    #[error("shape mismatch in {step}: {quantity} has shape {found:?}, expected {expected:?}")]
    Shape {
        /// The piece of the step.
        step: String,
        /// The array.
        quantity: String,
        /// The shape needed.
        expected: Vec<usize>,
        /// The shape given.
        found: Vec<usize>,
    },
    /// A NaN or infinity in an input of the step.
    #[error("non-finite value in {step}: {quantity} holds {count} NaN or infinite entries")]
    NonFinite {
        /// The piece of the step.
        step: String,
        /// The array.
        quantity: String,
        /// How many entries.
        count: usize,
    },
    /// A parameter out of range at step time (a viscosity ≤ 0, say).
    #[error("invalid {quantity} in {step}: {message}")]
    InvalidParameter {
        /// The piece of the step.
        step: String,
        /// The parameter.
        quantity: String,
        /// What is wrong.
        message: String,
    },
    /// The Courant number (or the explicit diffusion number) of a step exceeds
    /// the scheme's limit and substepping was not asked for.
    #[error("CFL violation in {step}: {quantity} number {number:.4} exceeds the limit {limit} (reduce dt, or enable substepping)")]
    Cfl {
        /// The piece of the step (`advection` or `explicit diffusion`).
        step: String,
        /// `courant` (`max |u| dt / h`) or `diffusion` (`ν dt (1/dx² + 1/dy²)`).
        quantity: String,
        /// The number found.
        number: f64,
        /// The limit.
        limit: f64,
    },
    /// The pressure or viscosity solve failed (did not converge, broke down).
    #[error("{step} failed ({quantity}): {source}")]
    Solve {
        /// `pressure solve` or `viscosity solve`.
        step: String,
        /// `pressure` or `velocity`.
        quantity: String,
        /// The solver's error.
        #[source]
        source: CgError,
    },
    /// An error of the direct pressure solver.
    #[error("pressure solve (sparse Cholesky) failed: {0}")]
    Direct(String),
    /// An error from the tape.
    #[error(transparent)]
    Tape(TapeError),
    /// An error from an operator of diffphys-ops.
    #[error(transparent)]
    Ops(#[from] OpsError),
}

impl FlowError {
    pub(crate) fn scene(what: &str, message: impl Into<String>) -> Self {
        FlowError::InvalidScene {
            what: what.to_string(),
            message: message.into(),
        }
    }

    pub(crate) fn shape(step: &str, quantity: &str, expected: &[usize], found: &[usize]) -> Self {
        FlowError::Shape {
            step: step.to_string(),
            quantity: quantity.to_string(),
            expected: expected.to_vec(),
            found: found.to_vec(),
        }
    }

    pub(crate) fn parameter(step: &str, quantity: &str, message: impl Into<String>) -> Self {
        FlowError::InvalidParameter {
            step: step.to_string(),
            quantity: quantity.to_string(),
            message: message.into(),
        }
    }

    /// What kind of error this is, in the tape's vocabulary.
    pub fn kind(&self) -> ErrorKind {
        match self {
            FlowError::InvalidScene { .. } | FlowError::InvalidParameter { .. } => {
                ErrorKind::InvalidArgument
            }
            FlowError::Shape { .. } => ErrorKind::Shape,
            FlowError::NonFinite { .. } => ErrorKind::NonFinite,
            FlowError::Cfl { .. } => ErrorKind::Unstable,
            FlowError::Solve { source, .. } => source.kind(),
            FlowError::Direct(_) => ErrorKind::Unstable,
            FlowError::Tape(t) => t.kind(),
            FlowError::Ops(o) => o.kind(),
        }
    }

    /// A tape error back as the flow error it carries, if it carries one
    /// (an op of this crate failed inside the tape), else wrapped.
    pub fn from_tape(e: TapeError) -> Self {
        match e {
            TapeError::Op { cause, op, kind } => match cause.downcast::<FlowError>() {
                Ok(flow) => *flow,
                Err(cause) => FlowError::Tape(TapeError::Op { op, cause, kind }),
            },
            other => FlowError::Tape(other),
        }
    }
}

impl From<TapeError> for FlowError {
    fn from(e: TapeError) -> Self {
        FlowError::from_tape(e)
    }
}

/// A flow error raised inside an op's forward or backward, as the tape's
/// error (kept as its source, with its kind).
impl From<FlowError> for TapeError {
    fn from(e: FlowError) -> Self {
        match e {
            FlowError::Tape(t) => t,
            other => {
                let kind = other.kind();
                let op = match &other {
                    FlowError::Shape { step, .. }
                    | FlowError::NonFinite { step, .. }
                    | FlowError::InvalidParameter { step, .. }
                    | FlowError::Cfl { step, .. }
                    | FlowError::Solve { step, .. } => step.clone(),
                    _ => "flow step".to_string(),
                };
                TapeError::op_of_kind(&op, other, kind)
            }
        }
    }
}

/// Result alias of the flow crate.
pub type Result<T, E = FlowError> = std::result::Result<T, E>;
