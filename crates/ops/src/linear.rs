//! The matrix-free linear operator trait that stencils implement and solvers consume.

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};

use crate::{CellMask, OpsError, Result};

/// `x` in `f64`, for reductions. (`Real::as_f64` is not `#[inline]` across
/// crates, which keeps reduction loops from vectorising; num-traits'
/// conversion is.)
#[inline(always)]
pub(crate) fn wide<T: Real>(x: T) -> f64 {
    x.to_f64().unwrap_or(f64::NAN)
}

/// A linear map `A: ℝ^{input_shape} → ℝ^{output_shape}` given by its action and the
/// action of its transpose, never by its matrix.
///
/// Implementors write [`LinearOperator::apply_into`] and
/// [`LinearOperator::apply_transpose_into`] on arrays whose shapes the caller has
/// checked; the provided [`LinearOperator::apply`] and
/// [`LinearOperator::apply_transpose`] check shapes and allocate. Every implementor
/// passes the dot-product test `<A x, y> = <x, Aᵀ y>`.
///
/// Operators are `Send + Sync`: a large solve runs whole on one of the thread
/// pool's workers ([`diffphys_tape::parallel::on_pool`]), so that its kernels
/// split across cores without handing work to the pool at every call.
pub trait LinearOperator<T: Real>: Send + Sync {
    /// A short name for errors and reports.
    fn name(&self) -> &str;

    /// Shape of `x` in `A x`.
    fn input_shape(&self) -> &[usize];

    /// Shape of `A x`.
    fn output_shape(&self) -> &[usize];

    /// `out = A x`. Shapes are the caller's responsibility (checked by
    /// [`LinearOperator::apply`]); implementations may panic on a mismatch.
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>);

    /// `out = Aᵀ y`, shapes as in [`LinearOperator::apply_into`] but swapped.
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>);

    /// `out = A x`, returning `<x, A x>` accumulated in `f64` whatever `T`: the
    /// curvature that conjugate gradient needs each iteration (summed in `T`, an
    /// `f32` curvature over a large grid loses enough digits to cost CG a fifth
    /// more iterations). Stencils override this to compute the dot product in the
    /// same pass over memory as the stencil; the default applies, then sums.
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, mut out: ArrayViewMutD<'_, T>) -> f64 {
        self.apply_into(x.view(), out.view_mut());
        ndarray::Zip::from(&x)
            .and(&out)
            .fold(0.0, |acc, &a, &b| acc + wide(a) * wide(b))
    }

    /// True if `A = Aᵀ` (then solvers may use `apply` for both directions).
    fn is_symmetric(&self) -> bool {
        false
    }

    /// The diagonal of `A` (shape [`LinearOperator::output_shape`]), for Jacobi
    /// preconditioning; `None` if the operator cannot say cheaply.
    fn diagonal(&self) -> Option<ArrayD<T>> {
        None
    }

    /// The nonzeros of `A` as `(row, column, value)` over row-major flattened
    /// indices, for assembling a sparse matrix (the exact reference solves);
    /// `None` if the operator cannot say cheaply.
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        None
    }

    /// `A x`, allocated.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `x` is not of [`LinearOperator::input_shape`].
    fn apply(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        if x.shape() != self.input_shape() {
            return Err(OpsError::shape(self.name(), self.input_shape(), x.shape()));
        }
        let mut out = ArrayD::zeros(IxDyn(self.output_shape()));
        self.apply_into(x, out.view_mut());
        Ok(out)
    }

    /// `Aᵀ y`, allocated.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `y` is not of [`LinearOperator::output_shape`].
    fn apply_transpose(&self, y: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        if y.shape() != self.output_shape() {
            return Err(OpsError::shape(self.name(), self.output_shape(), y.shape()));
        }
        let mut out = ArrayD::zeros(IxDyn(self.input_shape()));
        self.apply_transpose_into(y, out.view_mut());
        Ok(out)
    }
}

/// The null space of a singular symmetric positive semidefinite operator, which
/// solvers project out ([`crate::cg`]: of the right-hand side, the
/// preconditioned residuals and the solution). A property of the operator,
/// so it lives beside [`LinearOperator`] (re-exported as `cg::NullSpace`).
///
/// For an operator with `A k = 0` (all-Neumann or periodic Laplacians: `k` the
/// constants), `A x = b` is solvable only for `b ⟂ k`; CG solves
/// `A x = Π b` with `Π = I − k kᵀ / (kᵀ k)` and returns the solution with
/// `kᵀ x = 0` (for constants, zero mean).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum NullSpace {
    /// `A` is positive definite.
    #[default]
    None,
    /// The constants: the mean is removed.
    Constant,
    /// The constants on the active cells of a mask (zero on the others, where
    /// the operator is typically the identity): the mean over the active cells
    /// is removed from them.
    ConstantOn(CellMask),
}
