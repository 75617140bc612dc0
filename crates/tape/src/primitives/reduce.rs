//! Reductions: sum of all elements.

use ndarray::{ArrayD, ArrayViewD, IxDyn};

use crate::{BackwardArgs, Op, Real, Result, Var};

/// `y = Σᵢ xᵢ` (a 0-d array). Adjoint: `grad_x = grad_y` broadcast to x's shape.
struct Sum;

impl<T: Real> Op<T> for Sum {
    fn name(&self) -> &str {
        "sum"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        Ok(vec![ArrayD::from_elem(IxDyn(&[]), inputs[0].sum())])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let g = args.grad_out().first().copied().unwrap_or_else(T::zero);
        Ok(vec![Some(ArrayD::from_elem(args.input(0).raw_dim(), g))])
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// The sum of all elements, a 0-d value. Adjoint: the incoming gradient copied
    /// to every element.
    ///
    /// # Errors
    /// Only [`crate::TapeError::NonFinite`] if the sum overflows.
    pub fn sum(self) -> Result<Var<'t, T>> {
        self.apply1(Sum, &[])
    }
}
