//! # diffphys-ops
//!
//! PDE operators for diffphys. Every operator is first a pair of plain functions on
//! ndarray views, its forward and its vector–Jacobian product, that know nothing of
//! the tape; the tape plug-in ([`diffphys_tape::Op`]) is a thin adapter over them.
#![warn(missing_docs)]

pub mod advection;
pub mod cg;
pub mod conductivity;
pub mod dense;
mod error;
pub mod grid;
pub mod linear;
pub mod mac;
pub mod multigrid;
pub mod poisson;
pub mod projection;
pub mod reference;
pub mod stencil;
pub mod tape_ops;

pub use error::{OpsError, Result};
pub use grid::{Boundary, CellMask, Grid1, Grid2};
pub use linear::LinearOperator;
