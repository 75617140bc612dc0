//! The one error type of the operators crate.

use diffphys_tape::{ErrorKind, TapeError};

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
    Cg(#[from] CgError),
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

/// Why [`conjugate_gradient`](crate::cg::conjugate_gradient) failed. Every failure is detected and named; CG
/// never returns NaN silently.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CgError {
    /// The tolerance was not met within the iteration cap. The solution array
    /// holds the last iterate.
    #[error(
        "conjugate gradient did not converge in {iterations} iterations: residual \
         {residual:.3e} (relative {relative_residual:.3e}) above the target {target:.3e}"
    )]
    NoConvergence {
        /// Iterations performed.
        iterations: usize,
        /// The true residual `‖b − A x‖` of the last iterate.
        residual: f64,
        /// `residual / ‖b‖`.
        relative_residual: f64,
        /// The residual that was asked for, `max(rel_tol·‖b‖, abs_tol)`.
        target: f64,
    },
    /// The tolerance lies below what the precision can reach on this system:
    /// the recurrence residual met it, but the true residual `‖b − A x‖`,
    /// recomputed, stalled above it near the rounding floor, where restarting
    /// no longer gains. The solution array holds the last iterate, which is
    /// converged to working precision. Returned only with
    /// [`CgParams::require_convergence`](crate::cg::CgParams::require_convergence);
    /// otherwise [`CgInfo::rounding_floor`](crate::cg::CgInfo::rounding_floor)
    /// flags the same outcome.
    #[error(
        "conjugate gradient cannot reach the relative residual {requested:.1e} in {precision}: \
         the true residual stalled at {reached:.3e} after {iterations} iterations ({restarts} \
         restarts), near the estimated rounding floor {floor:.1e}; ask for a tolerance above \
         the floor, or solve in higher precision"
    )]
    BelowRoundingFloor {
        /// `f32` or `f64`.
        precision: String,
        /// The relative tolerance asked for, `max(rel_tol, abs_tol/‖b‖)`.
        requested: f64,
        /// The true relative residual `‖b − A x‖/‖b‖` reached.
        reached: f64,
        /// The estimated rounding floor of the relative residual,
        /// `ε·‖diag(A) ⊙ x‖/‖b‖`.
        floor: f64,
        /// Iterations performed.
        iterations: usize,
        /// Restarts from the recomputed residual.
        restarts: usize,
    },
    /// A direction `p` with `<p, A p> ≤ 0` (or a non-positive diagonal entry for
    /// Jacobi): the operator is not positive definite, or it is singular and no
    /// [`NullSpace`](crate::linear::NullSpace) was given.
    #[error(
        "operator is not positive definite: curvature <p, A p> = {curvature:e} at iteration \
         {iteration} (a singular operator needs CgParams::null_space)"
    )]
    NotPositiveDefinite {
        /// The iteration (0 for the diagonal check).
        iteration: usize,
        /// `<p, A p>` of the normalised system (or the diagonal entry).
        curvature: f64,
    },
    /// NaN or infinity in an input or in the recurrences.
    #[error("non-finite value in {what} at iteration {iteration}")]
    NonFinite {
        /// The iteration (0 for the inputs).
        iteration: usize,
        /// Which quantity.
        what: String,
    },
    /// An array does not have the operator's shape.
    #[error("shape mismatch in conjugate_gradient: {what} has shape {found:?}, the operator needs {expected:?}")]
    ShapeMismatch {
        /// Which array.
        what: String,
        /// The operator's shape.
        expected: Vec<usize>,
        /// The array's shape.
        found: Vec<usize>,
    },
    /// The recurrence cannot continue although the residual is not small: a step
    /// length overflows the precision (a curvature that underflows), or the
    /// preconditioned residual `<r, M⁻¹ r>` became non-positive.
    #[error("conjugate gradient broke down at iteration {iteration}: {reason}")]
    Breakdown {
        /// The iteration.
        iteration: usize,
        /// What happened.
        reason: String,
    },
    /// The operator or the parameters cannot be used (not square, not symmetric,
    /// no diagonal for Jacobi, a negative tolerance, an empty null space).
    #[error("invalid argument to conjugate_gradient: {message}")]
    InvalidArgument {
        /// What was wrong.
        message: String,
    },
}

impl CgError {
    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        CgError::InvalidArgument {
            message: message.into(),
        }
    }

    pub(crate) fn non_finite(iteration: usize, what: &str) -> Self {
        CgError::NonFinite {
            iteration,
            what: what.to_string(),
        }
    }
}
