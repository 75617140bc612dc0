//! Any [`LinearOperator`] as a tape op: forward `y = A x`, adjoint `grad_x = Aᵀ grad_y`.
//!
//! ```
//! use std::sync::Arc;
//! use diffphys_ops::{stencil::Laplacian1, tape_ops::LinearOp, Boundary, Grid1};
//! use diffphys_tape::{arr_dyn, Tape};
//!
//! let lap = Arc::new(Laplacian1::new(Grid1::new(4, 1.0, 0.0, Boundary::Periodic)?));
//! let tape = Tape::<f64>::new();
//! let x = tape.var(arr_dyn(&[0.0, 1.0, 0.0, 0.0]));
//! let y = tape.apply(LinearOp::new(Arc::clone(&lap)), &[x])?; // ∇²x = [1, −2, 1, 0]
//! let loss = y.sum()?;
//! let grads = tape.backward(loss, &[x])?;
//! // grad_x = Aᵀ·1 = 0: the periodic Laplacian sums to zero over each column.
//! assert!(grads.get(x).unwrap().iter().all(|g| g.abs() < 1e-15));
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```

use std::sync::Arc;

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::ArrayViewMutD;

use crate::{LinearOperator, OpsError};

/// A tape op that applies a linear operator `A`: forward `y = A x`, backward
/// `grad_x = Aᵀ grad_y` (computed only when `x` needs a gradient).
///
/// `A` is held by value; ops on the tape must be `'static`, so share a large
/// operator as an `Arc<A>` (which is itself a [`LinearOperator`]). The op keeps
/// nothing beyond the operator: the adjoint needs no input values.
#[derive(Debug, Clone)]
pub struct LinearOp<A> {
    op: A,
}

impl<A> LinearOp<A> {
    /// Wraps `op`.
    pub fn new(op: A) -> Self {
        LinearOp { op }
    }

    /// The operator.
    pub fn operator(&self) -> &A {
        &self.op
    }
}

impl<A> LinearOp<Transpose<A>> {
    /// The op of the transpose: forward `y = Aᵀ x`, backward `grad_x = A grad_y`.
    pub fn transposed(op: A) -> Self {
        LinearOp::new(Transpose(op))
    }
}

impl<T: Real, A: LinearOperator<T>> Op<T> for LinearOp<A> {
    fn name(&self) -> &str {
        self.op.name()
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        if inputs.len() != 1 {
            return Err(TapeError::Arity {
                op: self.op.name().to_string(),
                expected: 1,
                found: inputs.len(),
            });
        }
        let x = inputs[0].view();
        if x.shape() != self.op.input_shape() {
            return Err(OpsError::shape(self.op.name(), self.op.input_shape(), x.shape()).into());
        }
        // A pooled buffer (on an unrolled solver's tape, one per iteration),
        // zeroed: `apply_into` may accumulate into its output.
        let mut out = diffphys_tape::pool::take_zeroed_array(self.op.output_shape());
        self.op.apply_into(x, out.view_mut());
        Ok(vec![out])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) {
            return Ok(vec![None]);
        }
        let g = args.grad_out();
        if g.shape() != self.op.output_shape() {
            return Err(OpsError::shape(self.op.name(), self.op.output_shape(), g.shape()).into());
        }
        let mut out = diffphys_tape::pool::take_zeroed_array(self.op.input_shape());
        self.op.apply_transpose_into(g.view(), out.view_mut());
        Ok(vec![Some(out)])
    }
}

/// The transpose `Aᵀ` of a linear operator, itself a linear operator.
#[derive(Debug, Clone)]
pub struct Transpose<A>(pub A);

impl<T: Real, A: LinearOperator<T>> LinearOperator<T> for Transpose<A> {
    fn name(&self) -> &str {
        self.0.name()
    }
    fn input_shape(&self) -> &[usize] {
        self.0.output_shape()
    }
    fn output_shape(&self) -> &[usize] {
        self.0.input_shape()
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.0.apply_transpose_into(x, out);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.0.apply_into(y, out);
    }
    fn is_symmetric(&self) -> bool {
        self.0.is_symmetric()
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        self.0.diagonal()
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        self.0
            .triplets()
            .map(|t| t.into_iter().map(|(r, c, v)| (c, r, v)).collect())
    }
}

/// Forwards every method to the pointee.
macro_rules! forward_linear_operator {
    ($ptr:ident) => {
        /// A shared or boxed operator is the operator.
        impl<T: Real, A: LinearOperator<T> + ?Sized> LinearOperator<T> for $ptr<A> {
            fn name(&self) -> &str {
                (**self).name()
            }
            fn input_shape(&self) -> &[usize] {
                (**self).input_shape()
            }
            fn output_shape(&self) -> &[usize] {
                (**self).output_shape()
            }
            fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
                (**self).apply_into(x, out)
            }
            fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
                (**self).apply_transpose_into(y, out)
            }
            fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
                (**self).apply_into_dot(x, out)
            }
            fn is_symmetric(&self) -> bool {
                (**self).is_symmetric()
            }
            fn diagonal(&self) -> Option<ArrayD<T>> {
                (**self).diagonal()
            }
            fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
                (**self).triplets()
            }
        }
    };
}

forward_linear_operator!(Arc);
forward_linear_operator!(Box);
