//! # diffphys-ops
//!
//! PDE operators for diffphys. Every operator is first a pair of plain functions on
//! ndarray views, its forward and its vector–Jacobian product, that know nothing of
//! the tape; the tape plug-in ([`diffphys_tape::Op`]) is a thin adapter over them.
#![warn(missing_docs)]

mod error;
pub mod grid;
pub mod linear;

pub use error::{OpsError, Result};
pub use grid::{Boundary, Grid1, Grid2};
pub use linear::LinearOperator;
