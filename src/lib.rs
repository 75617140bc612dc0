//! # diffphys
//!
//! Differentiable physics in Rust: a reverse-mode autodiff tape over `ndarray`
//! tensors ([`tape`]), PDE operators that join it with hand-written adjoints
//! ([`ops`]), neural-network layers that train through them ([`nn`]), training
//! through the solver as a library ([`learn`]) and a differentiable 2D
//! incompressible flow step ([`flow`]). With the `harness` feature it also
//! re-exports the measurement of naive versus implicit gradients through
//! conjugate gradient (`compare`). This crate only re-exports them; one import
//! brings what the tutorials use:
//!
//! ```
//! use diffphys::prelude::*;
//!
//! // f(x) = Σ (x − 1)², ∂f/∂x = 2 (x − 1).
//! let mut params = vec![array![0.0, 2.0, 5.0].into_dyn()];
//! let tape = Tape::<f64>::new();
//! let x = tape.var(params[0].clone());
//! let d = x.sub(tape.scalar(1.0))?;
//! let loss = d.mul(d)?.sum()?;
//! let grads = tape.backward(loss, &[x])?;
//! assert_eq!(grads.get(x).unwrap(), &array![-2.0, 2.0, 8.0].into_dyn());
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
//! assert_eq!(params[0], array![1.0, 1.0, 1.0].into_dyn());
//! # Ok::<(), TapeError>(())
//! ```
//!
//! Every op joins a tape the same way: an op value recorded with
//! `tape.apply(op, &[inputs])` (`tape.apply_multi` for several outputs); the
//! primitives are also methods on [`Var`](tape::Var) (`x.mul(y)?`). The README's
//! "A first program" section is a first program (advect, solve, differentiate,
//! step an optimizer), compiled and run as a doctest; the tutorials in `docs/`
//! walk through the examples in `examples/`, starting with
//! `docs/01-tape-and-custom-ops.md` (`cargo run --release --example custom_op`),
//! and `.ci/book` renders them as a book (mdBook) with this reference beside it.
//! ARCHITECTURE.md draws the layers.
#![warn(missing_docs)]

#[cfg(feature = "harness")]
pub use diffphys_compare as compare;
pub use diffphys_flow as flow;
pub use diffphys_hybrid as hybrid;
pub use diffphys_learn as learn;
pub use diffphys_nn as nn;
pub use diffphys_ops as ops;
pub use diffphys_report as report;
pub use diffphys_tape as tape;
/// The random-number crate that seeded initialisation takes (`StdRng`), so a
/// user needs no version of their own to match ours.
pub use rand;

pub mod prelude;

#[cfg(doctest)]
mod docs;
