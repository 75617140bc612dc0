//! Linear algebra on 2-D values: matrix product and transpose.

use ndarray::{ArrayD, ArrayView2, ArrayViewD, Ix2};

use super::linear::{Linear, LinearMap};
use crate::{BackwardArgs, Op, Real, Result, TapeError, Var};

/// A 2-D view of `x`, or an error naming `op` and the shape.
fn as_matrix<'a, T: Real>(op: &str, x: &ArrayViewD<'a, T>) -> Result<ArrayView2<'a, T>> {
    x.clone().into_dimensionality::<Ix2>().map_err(|_| {
        TapeError::invalid(op, format!("needs a 2-D value, got shape {:?}", x.shape()))
    })
}

/// `C = A B` for `A` (m×k) and `B` (k×n). Adjoint: `grad_A = grad_C Bᵀ`,
/// `grad_B = Aᵀ grad_C`.
struct Matmul;

impl<T: Real> Op<T> for Matmul {
    fn name(&self) -> &str {
        "matmul"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let a = as_matrix("matmul", &inputs[0])?;
        let b = as_matrix("matmul", &inputs[1])?;
        if a.ncols() != b.nrows() {
            return Err(TapeError::shape("matmul", a.shape(), b.shape()));
        }
        Ok(vec![a.dot(&b).into_dyn()])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let a = as_matrix("matmul", args.input(0))?;
        let b = as_matrix("matmul", args.input(1))?;
        let g = as_matrix("matmul", args.grad_out())?;
        Ok(vec![
            args.needs(0).then(|| g.dot(&b.t()).into_dyn()),
            args.needs(1).then(|| a.t().dot(&g).into_dyn()),
        ])
    }
}

/// `y = xᵀ` for a 2-D `x`, stored in standard (row-major) layout. Adjoint:
/// `grad_x = grad_yᵀ`.
struct Transpose;

impl<T: Real> LinearMap<T> for Transpose {
    const NAME: &'static str = "transpose";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        let x = as_matrix("transpose", &x)?;
        Ok(x.t().as_standard_layout().into_owned().into_dyn())
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, _x_shape: &[usize]) -> ArrayD<T> {
        grad.t().as_standard_layout().into_owned()
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// The matrix product `C = A B` of a 2-D `self` (m×k) and a 2-D `other` (k×n).
    /// Adjoint: `grad_A = grad_C Bᵀ`, `grad_B = Aᵀ grad_C`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `matmul` if either value is not 2-D;
    /// [`TapeError::ShapeMismatch`] if the inner dimensions differ;
    /// [`TapeError::ForeignVar`] if `other` is on another tape.
    pub fn matmul(self, other: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Matmul, &[self, other])
    }

    /// The transpose `y = xᵀ` of a 2-D value (`y[j, i] = x[i, j]`). Adjoint:
    /// `grad_x = grad_yᵀ`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `transpose` if the value is not 2-D.
    pub fn transpose(self) -> Result<Var<'t, T>> {
        self.tape.apply(Linear(Transpose), &[self])
    }
}

#[cfg(test)]
mod tests {
    use super::super::linear::assert_adjoint;
    use super::*;

    #[test]
    fn transpose_passes_the_dot_product_test_and_is_row_major() {
        assert_adjoint(&Transpose, &[3, 5]);
        let x = crate::test_array::<f64>(&[3, 5], 1);
        let y = LinearMap::<f64>::forward(&Transpose, x.view()).unwrap();
        assert!(y.is_standard_layout());
        assert_eq!(y[[4, 2]], x[[2, 4]]);
    }
}
