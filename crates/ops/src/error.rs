//! The one error type of the operators crate.

use diffphys_tape::{ErrorKind, TapeError};

use crate::cg::CgError;
use thiserror::Error;

/// Everything an operator can reject or fail at. Bad input is an error, never a panic.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum OpsError {
    /// Two shapes that had to agree did not.
    #[error("shape mismatch in {op}: expected {expected:?}, got {found:?}")]
    ShapeMismatch {
        /// The operator that checked.
        op: String,
        /// The shape it needed.
        expected: Vec<usize>,
        /// The shape it was given.
        found: Vec<usize>,
    },
    /// An argument other than a shape is out of range or meaningless.
    #[error("invalid argument to {op}: {message}")]
    InvalidArgument {
        /// The operator.
        op: String,
        /// What was wrong.
        message: String,
    },
    /// An explicit scheme was asked to step with a Courant number above its limit.
    #[error("CFL violation in {op}: Courant number {courant:.4} exceeds {limit} (max |u|·dt/dx); reduce dt or allow it explicitly")]
    Cfl {
        /// The operator.
        op: String,
        /// The largest `|u|·dt/dx` found.
        courant: f64,
        /// The stability limit.
        limit: f64,
    },
    /// An input or result holds NaN or infinity.
    #[error("non-finite value in {op}: {what}")]
    NonFinite {
        /// The operator.
        op: String,
        /// Which array.
        what: String,
    },
    /// An error from the tape (when an operator runs as a tape op).
    #[error(transparent)]
    Tape(#[from] TapeError),
    /// Conjugate gradient failed (in a solve that is not itself a tape op).
    #[error(transparent)]
    Cg(#[from] crate::cg::CgError),
}

impl OpsError {
    /// A [`OpsError::ShapeMismatch`].
    pub fn shape(op: &str, expected: &[usize], found: &[usize]) -> Self {
        OpsError::ShapeMismatch {
            op: op.to_string(),
            expected: expected.to_vec(),
            found: found.to_vec(),
        }
    }

    /// What kind of error this is, in the tape's vocabulary.
    pub fn kind(&self) -> ErrorKind {
        match self {
            OpsError::ShapeMismatch { .. } => ErrorKind::Shape,
            OpsError::InvalidArgument { .. } => ErrorKind::InvalidArgument,
            OpsError::Cfl { .. } => ErrorKind::Unstable,
            OpsError::NonFinite { .. } => ErrorKind::NonFinite,
            OpsError::Tape(t) => t.kind(),
            OpsError::Cg(c) => c.kind(),
        }
    }

    /// Whether a NaN or infinity caused this error.
    pub fn is_non_finite(&self) -> bool {
        self.kind() == ErrorKind::NonFinite
    }

    /// A [`OpsError::InvalidArgument`].
    pub fn invalid(op: &str, message: impl Into<String>) -> Self {
        OpsError::InvalidArgument {
            op: op.to_string(),
            message: message.into(),
        }
    }
}

/// Converts an operator error raised inside a plugin's forward or backward into the
/// tape's error, keeping it as the source. A tape error passes through unchanged.
impl From<OpsError> for TapeError {
    fn from(e: OpsError) -> Self {
        match e {
            OpsError::Tape(t) => t,
            other => {
                let op = match &other {
                    OpsError::ShapeMismatch { op, .. }
                    | OpsError::InvalidArgument { op, .. }
                    | OpsError::Cfl { op, .. }
                    | OpsError::NonFinite { op, .. } => op.clone(),
                    OpsError::Cg(_) => "conjugate_gradient".to_string(),
                    OpsError::Tape(_) => unreachable!("handled above"),
                };
                let kind = other.kind();
                TapeError::op_of_kind(&op, other, kind)
            }
        }
    }
}

impl CgError {
    /// What kind of error this is, in the tape's vocabulary.
    pub fn kind(&self) -> ErrorKind {
        match self {
            CgError::NoConvergence { .. } | CgError::BelowRoundingFloor { .. } => {
                ErrorKind::NotConverged
            }
            CgError::NotPositiveDefinite { .. } | CgError::Breakdown { .. } => ErrorKind::Unstable,
            CgError::NonFinite { .. } => ErrorKind::NonFinite,
            CgError::ShapeMismatch { .. } => ErrorKind::Shape,
            CgError::InvalidArgument { .. } => ErrorKind::InvalidArgument,
        }
    }

    /// Whether a NaN or infinity caused this error.
    pub fn is_non_finite(&self) -> bool {
        self.kind() == ErrorKind::NonFinite
    }
}

/// Converts a CG error raised inside a plugin's forward or backward into the
/// tape's error, keeping it as the source and its kind.
impl From<CgError> for TapeError {
    fn from(e: CgError) -> Self {
        let kind = e.kind();
        TapeError::op_of_kind("conjugate_gradient", e, kind)
    }
}

/// Result alias of the operators crate.
pub type Result<T, E = OpsError> = std::result::Result<T, E>;
