//! # diffphys-tape
//!
//! A reverse-mode automatic differentiation tape over `ndarray` tensors, generic
//! over [`Real`] (`f32` and `f64`). Every op records a node that keeps its output;
//! [`Tape::backward`] sweeps them in reverse, visiting only the nodes between the
//! requested variables and the loss. Plugins with hand-written adjoints join the
//! tape through the same [`Op`] trait as the primitives.
//!
//! There is one way to record an op: a value implementing [`Op`], passed to
//! [`Tape::apply`] with its inputs (`tape.apply(op, &[x, y])?`, one output) or
//! to [`Tape::apply_multi`] (several outputs). The primitives' methods on
//! [`Var`] (`x.mul(y)?`, `x.sum()?`) are sugar over the same call.
//!
//! ```
//! use diffphys_tape::{Tape, arr_dyn};
//!
//! let tape = Tape::<f64>::new();
//! let x = tape.var(arr_dyn(&[1.0, 2.0, 3.0]));
//! let y = x.mul(x)?.sum()?; // y = Σ x²
//! let grads = tape.backward(y, &[x])?;
//! assert_eq!(grads.get(x).unwrap().as_slice().unwrap(), &[2.0, 4.0, 6.0]); // dy/dx = 2x
//! # Ok::<(), diffphys_tape::TapeError>(())
//! ```
#![warn(missing_docs)]

mod backward;
pub mod checkpoint;
mod error;
pub mod gradcheck;
mod op;
mod operators;
pub mod optim;
pub mod parallel;
pub mod pool;
pub mod primitives;
mod real;
mod tape;

pub use backward::Gradients;
pub use checkpoint::{checkpointed_steps, Schedule, SegmentFn, StepFn};
pub use error::{ErrorKind, Pass, Result, TapeError};
pub use gradcheck::{
    check_adjoint, check_gradient, test_array, AdjointReport, GradCheckOptions, GradCheckReport,
};
pub use ndarray::{ArrayD, ArrayViewD, IxDyn};
pub use op::{BackwardArgs, Op};
pub use optim::{Adam, GradientDescent, Optimizer};
pub use real::{PerPrecision, Real};
pub use tape::{Tape, TapeStats, Var};

/// A 1-D dynamic-dimension array from a slice, the shape most examples start from.
pub fn arr_dyn<T: Clone>(values: &[T]) -> ArrayD<T> {
    ndarray::Array1::from(values.to_vec()).into_dyn()
}
