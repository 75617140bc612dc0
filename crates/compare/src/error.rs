//! The one error type of the comparison harness.

use diffphys_ops::OpsError;
use diffphys_tape::{ErrorKind, TapeError};
use thiserror::Error;

/// Everything the harness can reject or fail at. A failing gradient method is a
/// result to report (its row's `error` field), not a reason to stop a sweep; these
/// errors say what went wrong and where.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum CompareError {
    /// An operator rejected its input or failed (a solver that did not converge, …).
    #[error(transparent)]
    Ops(#[from] OpsError),
    /// The tape rejected an op or a gradient (shape, non-finite value, …).
    #[error(transparent)]
    Tape(#[from] TapeError),
    /// The naive (unrolled) CG failed inside one of its recorded iterations; the
    /// source names the op (for a non-finite value, which op produced it and in
    /// which pass).
    #[error("naive CG, iteration {iteration}: {source}")]
    NaiveIteration {
        /// The CG iteration (0-based) whose recording or backward failed.
        iteration: usize,
        /// The tape's error.
        #[source]
        source: TapeError,
    },
    /// A long unroll of an explicit step (upwind advection) failed at one of its
    /// steps; the source names the op (for a non-finite value, the op that
    /// produced it and in which pass).
    #[error("advection unroll, step {step}: {source}")]
    UnrollStep {
        /// The step (0-based) whose forward or backward failed; the number of
        /// steps if the loss after the last step failed.
        step: usize,
        /// The operator's (or tape's) error.
        #[source]
        source: OpsError,
    },
    /// A gradient or solution came out with NaN or infinity where the method itself
    /// did not catch it.
    #[error("non-finite value in {method}: {what}")]
    NonFinite {
        /// The gradient method.
        method: String,
        /// Which array.
        what: String,
    },
    /// Reading or writing a file failed.
    #[error("I/O error on {path}: {source}")]
    Io {
        /// The file or folder.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A chart could not be drawn (empty or degenerate data, or a drawing error).
    #[error("chart: {0}")]
    Chart(String),
    /// A chart, a progress display or a file of [`diffphys_report`] failed.
    #[error(transparent)]
    Report(#[from] diffphys_report::ReportError),
    /// Serialising results to JSON failed.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// An argument (a size, an iteration count, a precision name, …) is out of range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// A run was not attempted, and why (a naive tape that would not fit in the
    /// memory limit, say).
    #[error("skipped: {0}")]
    Skipped(String),
    /// A run was refused before it allocated: its estimated memory exceeds the
    /// limit (`--memory-limit-mib`, or the memory the machine has available).
    #[error(
        "memory limit: {method} on {n}×{n} cells needs about {} (estimated), over the limit of {} \
         ({source_of_limit}); not run",
        crate::format::format_bytes(*estimate_bytes),
        crate::format::format_bytes(*limit_bytes)
    )]
    MemoryLimit {
        /// The method refused (`naive`, `implicit`, `exact`, `baseline_cg`, `setup`).
        method: String,
        /// Cells per axis.
        n: usize,
        /// The estimated bytes of the run.
        estimate_bytes: usize,
        /// The limit it was checked against.
        limit_bytes: usize,
        /// Where the limit came from: `--memory-limit-mib`, `MemAvailable` or
        /// `fallback`.
        source_of_limit: String,
    },
    /// A grid too small for the run asked of it: a fixed count of unrolled CG
    /// iterations above the number of unknowns. CG reaches the exact solution
    /// within `unknowns` iterations; the iterations after that divide 0 by 0.
    #[error(
        "grid too small: {method} on {n}×{n} cells: {iterations} fixed CG iterations exceed \
         the {unknowns} unknowns (CG is exact within {unknowns} iterations; later ones divide \
         a vanished residual by itself, 0/0); \
         use a larger grid or at most {unknowns} iterations"
    )]
    GridTooSmall {
        /// The method refused.
        method: String,
        /// Cells per axis.
        n: usize,
        /// The fixed iteration count asked for.
        iterations: usize,
        /// Unknowns of the system (`n²`).
        unknowns: usize,
    },
    /// Nothing in a sweep could run (every run was refused or failed); the
    /// message counts the runs by how they ended and gives the memory guard's
    /// reason if it refused runs. The results were still written.
    #[error("no run succeeded: {0}")]
    NothingRan(String),
    /// A sweep completed runs but measured nothing to judge: runs failed and
    /// no floor was measured. The results were still written.
    #[error("nothing measured: {0}")]
    NothingMeasured(String),
}

impl CompareError {
    /// What kind of error this is: the kind of the tape's or operator's error it
    /// wraps, at any depth; [`ErrorKind::NonFinite`] for a gradient the harness
    /// found non-finite; [`ErrorKind::InvalidArgument`] for an argument, a grid
    /// too small or a run refused for memory or skipped; [`ErrorKind::Op`] for
    /// the harness's own failures (I/O, charts, JSON, nothing ran).
    pub fn kind(&self) -> ErrorKind {
        match self {
            CompareError::Ops(e) | CompareError::UnrollStep { source: e, .. } => e.kind(),
            CompareError::Tape(e) | CompareError::NaiveIteration { source: e, .. } => e.kind(),
            CompareError::NonFinite { .. } => ErrorKind::NonFinite,
            CompareError::InvalidArgument(_)
            | CompareError::Skipped(_)
            | CompareError::MemoryLimit { .. }
            | CompareError::GridTooSmall { .. } => ErrorKind::InvalidArgument,
            CompareError::Io { .. }
            | CompareError::Chart(_)
            | CompareError::Report(_)
            | CompareError::Json(_)
            | CompareError::NothingRan(_)
            | CompareError::NothingMeasured(_) => ErrorKind::Op,
        }
    }

    /// True if a NaN or infinity caused this error (as opposed to a bad argument
    /// or a solver that ran out of iterations), however deeply it is wrapped.
    pub fn is_non_finite(&self) -> bool {
        self.kind() == ErrorKind::NonFinite
    }

    /// A [`CompareError::Io`] on `path`.
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        CompareError::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }

    /// A [`CompareError::InvalidArgument`].
    pub fn invalid(message: impl Into<String>) -> Self {
        CompareError::InvalidArgument(message.into())
    }
}

/// Result alias of the comparison crate.
pub type Result<T, E = CompareError> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use diffphys_ops::cg::CgError;
    use diffphys_tape::Pass;

    use super::*;

    fn tape_nan() -> TapeError {
        TapeError::NonFinite {
            op: "mul".into(),
            pass: Pass::Backward,
            count: 1,
            len: 4,
        }
    }

    fn cg_nan() -> CgError {
        CgError::NonFinite {
            iteration: 3,
            what: "residual".into(),
        }
    }

    fn ops_nan() -> OpsError {
        OpsError::NonFinite {
            op: "poisson".into(),
            what: "rhs".into(),
        }
    }

    #[test]
    fn a_non_finite_error_is_recognised_at_every_depth() {
        let errors = [
            CompareError::NonFinite {
                method: "naive".into(),
                what: "gradient".into(),
            },
            CompareError::Tape(tape_nan()),
            CompareError::NaiveIteration {
                iteration: 2,
                source: tape_nan(),
            },
            CompareError::Ops(ops_nan()),
            CompareError::Ops(OpsError::Cg(cg_nan())),
            CompareError::Ops(OpsError::Tape(tape_nan())),
            CompareError::Tape(TapeError::from(ops_nan())),
            CompareError::Tape(TapeError::from(cg_nan())),
            CompareError::NaiveIteration {
                iteration: 0,
                source: TapeError::from(OpsError::Cg(cg_nan())),
            },
            CompareError::UnrollStep {
                step: 5,
                source: OpsError::Tape(TapeError::from(ops_nan())),
            },
            CompareError::Ops(OpsError::Tape(TapeError::from(cg_nan()))),
        ];
        for e in &errors {
            assert!(e.is_non_finite(), "not recognised as non-finite: {e:?}");
        }
    }

    #[test]
    fn other_errors_are_not_non_finite() {
        let cg = CgError::InvalidArgument {
            message: "rtol".into(),
        };
        let errors = [
            CompareError::invalid("n = 0"),
            CompareError::Skipped("too big".into()),
            CompareError::Chart("empty".into()),
            CompareError::Tape(TapeError::from(cg)),
        ];
        for e in &errors {
            assert!(!e.is_non_finite(), "{e:?}");
        }
        assert_eq!(errors[0].kind(), ErrorKind::InvalidArgument);
        assert_eq!(errors[3].kind(), ErrorKind::InvalidArgument);
    }
}
