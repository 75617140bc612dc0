//! The Python exception classes, one per kind of failure, and the conversion of
//! every Rust error of the bound crates into them (the message is the Rust one).

use diffphys_flow::FlowError;
use diffphys_ops::cg::CgError;
use diffphys_ops::OpsError;
use diffphys_tape::{ErrorKind, TapeError};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::PyErr;

create_exception!(
    diffphys,
    DiffphysError,
    PyException,
    "Base class of every error raised by diffphys."
);
create_exception!(
    diffphys,
    ShapeError,
    DiffphysError,
    "Arrays whose shapes do not fit the operator or each other."
);
create_exception!(
    diffphys,
    InvalidArgumentError,
    DiffphysError,
    "An argument out of range or meaningless (a negative tolerance, dt <= 0, an unknown boundary)."
);
create_exception!(
    diffphys,
    NonFiniteError,
    DiffphysError,
    "NaN or infinity in an input, a result or a gradient."
);
create_exception!(
    diffphys,
    NotConvergedError,
    DiffphysError,
    "An iterative solve did not reach its tolerance within its iteration cap."
);
create_exception!(
    diffphys,
    UnstableError,
    DiffphysError,
    "A scheme or solver met input it is unstable on: a CFL violation, an operator that is not positive definite, a breakdown."
);

/// The exception of a kind, with `message`.
pub(crate) fn of_kind(kind: ErrorKind, message: String) -> PyErr {
    match kind {
        ErrorKind::Shape => ShapeError::new_err(message),
        ErrorKind::InvalidArgument => InvalidArgumentError::new_err(message),
        ErrorKind::NonFinite => NonFiniteError::new_err(message),
        ErrorKind::NotConverged => NotConvergedError::new_err(message),
        ErrorKind::Unstable => UnstableError::new_err(message),
        _ => DiffphysError::new_err(message),
    }
}

/// A Rust error of one of the bound crates, as the exception of its kind.
pub(crate) trait ToPyErr {
    /// The exception.
    fn to_py(self) -> PyErr;
}

impl ToPyErr for OpsError {
    fn to_py(self) -> PyErr {
        of_kind(self.kind(), self.to_string())
    }
}

impl ToPyErr for CgError {
    fn to_py(self) -> PyErr {
        of_kind(self.kind(), self.to_string())
    }
}

impl ToPyErr for TapeError {
    fn to_py(self) -> PyErr {
        of_kind(self.kind(), full_message(&self))
    }
}

impl ToPyErr for FlowError {
    fn to_py(self) -> PyErr {
        of_kind(self.kind(), full_message(&self))
    }
}

/// The message of an error and of each of its sources, joined by `: ` (a tape
/// error wrapping a solver failure says both).
fn full_message(e: &dyn std::error::Error) -> String {
    let mut message = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let text = s.to_string();
        if !message.contains(&text) {
            message.push_str(": ");
            message.push_str(&text);
        }
        source = s.source();
    }
    message
}

/// `result` with its error converted ([`ToPyErr`]).
pub(crate) fn check<T, E: ToPyErr>(result: Result<T, E>) -> pyo3::PyResult<T> {
    result.map_err(ToPyErr::to_py)
}
