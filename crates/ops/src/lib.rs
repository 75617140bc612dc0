//! # diffphys-ops
//!
//! PDE operators for diffphys. Every operator is first a pair of plain functions on
//! ndarray views, its forward and its vector–Jacobian product, that know nothing of
//! the tape; the tape plug-in ([`diffphys_tape::Op`]) is a thin adapter over them,
//! recorded like any other op with `tape.apply(op, &[inputs])`.
//!
//! A Poisson solve `−∇² u = b` on the tape, with its implicit gradient (one
//! adjoint CG solve, not the iterations), checked against finite differences:
//!
//! ```
//! use std::sync::Arc;
//!
//! use diffphys_ops::cg::CgParams;
//! use diffphys_ops::poisson::PoissonSolve;
//! use diffphys_ops::stencil::Laplacian2;
//! use diffphys_ops::{Boundary, Grid2};
//! use diffphys_tape::{check_gradient, test_array, GradCheckOptions, Tape};
//!
//! let grid = Grid2::new(8, 8, 1.0 / 8.0, 1.0 / 8.0, Boundary::ZeroDirichlet)?;
//! let solve = PoissonSolve::new(
//!     Arc::new(Laplacian2::negative(grid)),
//!     CgParams::default().with_rel_tol(1e-12),
//! );
//! let b = test_array::<f64>(&[8, 8], 1);
//!
//! // L(b) = Σ u(b)², dL/db = 2 A⁻ᵀ u.
//! let tape = Tape::<f64>::new();
//! let bv = tape.var(b.clone());
//! let u = tape.apply(solve.clone(), &[bv])?;
//! let grads = tape.backward(u.mul(u)?.sum()?, &[bv])?;
//! assert_eq!(grads.get(bv).unwrap().shape(), &[8, 8]);
//!
//! let report = check_gradient(
//!     |tape, v| {
//!         let u = tape.apply(solve.clone(), &[v[0]])?;
//!         u.mul(u)?.sum()
//!     },
//!     &[b],
//!     GradCheckOptions::for_type::<f64>(),
//! )?;
//! assert!(report.passed, "{report:?}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
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
pub mod staggered;
pub mod stencil;
pub mod tape_ops;

pub use error::{OpsError, Result};
pub use grid::{Boundary, CellMask, Grid1, Grid2};
pub use linear::LinearOperator;
