//! The one error type of the tape.

use thiserror::Error;

/// Where in the computation a non-finite value appeared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pass {
    /// While evaluating an op's forward.
    Forward,
    /// While evaluating an op's backward (its vector–Jacobian product).
    Backward,
}

impl std::fmt::Display for Pass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Pass::Forward => "forward",
            Pass::Backward => "backward",
        })
    }
}

/// Everything that can go wrong while recording on a tape or sweeping it backwards.
///
/// Bad input is always an error, never a panic; messages name the op and the shapes.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum TapeError {
    /// Two shapes that had to agree (or broadcast) did not.
    #[error("shape mismatch in {op}: expected {expected:?}, found {found:?}")]
    ShapeMismatch {
        /// The op that checked the shapes.
        op: String,
        /// The shape it needed (for a binary op, the left operand's).
        expected: Vec<usize>,
        /// The shape it was given (for a binary op, the right operand's).
        found: Vec<usize>,
    },
    /// An argument other than a shape is out of range (an axis, a slice bound, a length).
    #[error("invalid argument to {op}: {message}")]
    InvalidArgument {
        /// The op that rejected its argument.
        op: String,
        /// What was wrong.
        message: String,
    },
    /// An op received a different number of inputs than it takes.
    #[error("{op} takes {expected} input(s), got {found}")]
    Arity {
        /// The op.
        op: String,
        /// Inputs it takes.
        expected: usize,
        /// Inputs it was given.
        found: usize,
    },
    /// `backward` was called on a non-scalar output without a seed gradient.
    #[error("backward needs a scalar loss or an explicit seed; the output has shape {shape:?}")]
    NonScalarLoss {
        /// Shape of the output that was passed as the loss.
        shape: Vec<usize>,
    },
    /// A variable recorded on another tape was passed to this one.
    #[error("{op}: variable belongs to tape {found}, not to tape {expected}")]
    ForeignVar {
        /// The op (or `backward`) that received it.
        op: String,
        /// The id of the tape doing the work.
        expected: u64,
        /// The id of the tape the variable came from.
        found: u64,
    },
    /// An op produced NaN or infinity.
    #[error("non-finite value ({count} of {len} entries) produced by the {pass} of {op}")]
    NonFinite {
        /// The op that produced it.
        op: String,
        /// Forward or backward.
        pass: Pass,
        /// How many entries were non-finite.
        count: usize,
        /// How many entries the array had.
        len: usize,
    },
    /// A plugin op was asked for a gradient it does not implement.
    #[error("backward is not supported by op {op}")]
    BackwardNotSupported {
        /// The op.
        op: String,
    },
    /// [`crate::Gradients::try_get`] was asked for a variable it holds no gradient of.
    #[error("no gradient for variable {index} of tape {tape}: it was not requested from backward, or it is on another tape")]
    NoGradient {
        /// The variable's index on its tape.
        index: usize,
        /// The variable's tape.
        tape: u64,
    },
    /// A plugin op failed for a reason of its own (a solver that did not converge, say).
    ///
    /// The message includes the cause's message (`poisson_solve failed: conjugate
    /// gradient did not converge …`), so the cause is not also reported as
    /// [`std::error::Error::source`]: an error chain prints it once. The cause
    /// keeps its own type: downcast the `cause` field (or
    /// [`TapeError::op_cause`]) to read its fields.
    #[error("{op} failed: {cause}")]
    Op {
        /// The op.
        op: String,
        /// The op's own error.
        cause: Box<dyn std::error::Error + Send + Sync + 'static>,
        /// What kind of failure the cause is, as its crate classified it
        /// ([`ErrorKind::Op`] when it did not).
        kind: ErrorKind,
    },
}

/// What kind of error a [`TapeError`] is, for callers that branch on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// Shapes that had to agree did not.
    Shape,
    /// An argument out of range, or the wrong number of inputs.
    InvalidArgument,
    /// A non-scalar loss without a seed.
    NonScalarLoss,
    /// A variable of another tape.
    ForeignVar,
    /// NaN or infinity in a value or a gradient.
    NonFinite,
    /// An op without a backward was asked for one.
    BackwardNotSupported,
    /// A gradient that was not computed was asked for.
    NoGradient,
    /// An iterative solver did not reach its tolerance (out of iterations, or
    /// asked for less than its precision's rounding floor).
    NotConverged,
    /// A scheme or solver met input it is unstable on: a CFL violation, an
    /// operator that is not positive definite, a breakdown.
    Unstable,
    /// A plugin op's own failure, not classified further.
    Op,
}

impl TapeError {
    /// What kind of error this is.
    pub fn kind(&self) -> ErrorKind {
        match self {
            TapeError::ShapeMismatch { .. } => ErrorKind::Shape,
            TapeError::InvalidArgument { .. } | TapeError::Arity { .. } => {
                ErrorKind::InvalidArgument
            }
            TapeError::NonScalarLoss { .. } => ErrorKind::NonScalarLoss,
            TapeError::ForeignVar { .. } => ErrorKind::ForeignVar,
            TapeError::NonFinite { .. } => ErrorKind::NonFinite,
            TapeError::BackwardNotSupported { .. } => ErrorKind::BackwardNotSupported,
            TapeError::NoGradient { .. } => ErrorKind::NoGradient,
            TapeError::Op { kind, .. } => *kind,
        }
    }

    /// Whether a NaN or infinity caused this error: a [`TapeError::NonFinite`],
    /// or a plugin's error that its crate classified so.
    pub fn is_non_finite(&self) -> bool {
        self.kind() == ErrorKind::NonFinite
    }

    /// `Ok` if an op that takes `expected` inputs got `found`, else
    /// [`TapeError::Arity`] naming `op`: the one check every op's forward starts with.
    pub fn check_arity(op: &str, expected: usize, found: usize) -> Result<()> {
        if expected == found {
            Ok(())
        } else {
            Err(TapeError::Arity {
                op: op.to_string(),
                expected,
                found,
            })
        }
    }

    /// A [`TapeError::ShapeMismatch`] for `op`: it needed `expected`, it got `found`.
    pub fn shape(op: &str, expected: &[usize], found: &[usize]) -> Self {
        TapeError::ShapeMismatch {
            op: op.to_string(),
            expected: expected.to_vec(),
            found: found.to_vec(),
        }
    }

    /// A [`TapeError::InvalidArgument`] for `op`.
    pub fn invalid(op: &str, message: impl Into<String>) -> Self {
        TapeError::InvalidArgument {
            op: op.to_string(),
            message: message.into(),
        }
    }

    /// Wraps a plugin's own error as [`TapeError::Op`]. A [`TapeError`] keeps
    /// its kind; any other error is [`ErrorKind::Op`] (see [`TapeError::op_of_kind`]).
    pub fn op(op: &str, cause: impl std::error::Error + Send + Sync + 'static) -> Self {
        let cause: Box<dyn std::error::Error + Send + Sync + 'static> = Box::new(cause);
        let kind = cause
            .downcast_ref::<TapeError>()
            .map_or(ErrorKind::Op, TapeError::kind);
        TapeError::Op {
            op: op.to_string(),
            cause,
            kind,
        }
    }

    /// The plugin's own error of a [`TapeError::Op`] (downcast it to its type),
    /// `None` for every other variant.
    pub fn op_cause(&self) -> Option<&(dyn std::error::Error + Send + Sync + 'static)> {
        match self {
            TapeError::Op { cause, .. } => Some(cause.as_ref()),
            _ => None,
        }
    }

    /// Wraps a plugin's own error as [`TapeError::Op`] of a kind its crate
    /// determined, so that callers can classify it without knowing its type.
    pub fn op_of_kind(
        op: &str,
        cause: impl std::error::Error + Send + Sync + 'static,
        kind: ErrorKind,
    ) -> Self {
        TapeError::Op {
            op: op.to_string(),
            cause: Box::new(cause),
            kind,
        }
    }
}

/// Result alias of the tape crate.
pub type Result<T, E = TapeError> = std::result::Result<T, E>;
