//! # diffphys
//!
//! Differentiable physics in Rust: a reverse-mode autodiff tape over `ndarray`
//! tensors ([`tape`]), PDE operators that join it with hand-written adjoints
//! ([`ops`]), a differentiable incompressible flow step built on them ([`flow`]),
//! neural-network layers that train through them ([`nn`]), and the
//! measurement of naive versus implicit gradients through conjugate gradient
//! ([`compare`]). This crate only re-exports them, with the most
//! used items at the top level.
//!
//! A gradient, checked against finite differences, then one optimizer step:
//!
//! ```
//! use diffphys::{arr_dyn, check_gradient, GradCheckOptions, GradientDescent, Optimizer, Tape};
//!
//! // f(x) = Σ (x − 1)², ∂f/∂x = 2 (x − 1).
//! let mut params = vec![arr_dyn(&[0.0, 2.0, 5.0])];
//! let tape = Tape::<f64>::new();
//! let x = tape.var(params[0].clone());
//! let d = x.sub(tape.scalar(1.0))?;
//! let loss = d.mul(d)?.sum()?;
//! let grads = tape.backward(loss, &[x])?;
//! assert_eq!(grads.get(x).unwrap(), &arr_dyn(&[-2.0, 2.0, 8.0]));
//!
//! let report = check_gradient(
//!     |tape, v| {
//!         let d = v[0].sub(tape.scalar(1.0))?;
//!         d.mul(d)?.sum()
//!     },
//!     &params,
//!     GradCheckOptions::for_type::<f64>(),
//! )?;
//! assert!(report.passed, "{report:?}");
//!
//! // x ← x − 0.5 · 2 (x − 1) lands on the minimiser x = 1 in one step.
//! GradientDescent::new(0.5).step_vars(&mut params, &grads, &[x])?;
//! assert_eq!(params[0], arr_dyn(&[1.0, 1.0, 1.0]));
//! # Ok::<(), diffphys::TapeError>(())
//! ```
//!
//! The tutorials in `docs/` walk through the examples in `examples/`, starting with
//! `docs/01-tape-and-custom-ops.md` (`cargo run --release --example custom_op`).
#![warn(missing_docs)]

pub use diffphys_compare as compare;
pub use diffphys_flow as flow;
pub use diffphys_learn as learn;
pub use diffphys_nn as nn;
pub use diffphys_ops as ops;
pub use diffphys_tape as tape;

pub use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator, OpsError};
pub use diffphys_tape::{
    arr_dyn, check_adjoint, check_gradient, test_array, Adam, AdjointReport, ArrayD, ArrayViewD,
    BackwardArgs, GradCheckOptions, GradCheckReport, GradientDescent, Gradients, Op, Optimizer,
    Real, Tape, TapeError, TapeStats, Var,
};
