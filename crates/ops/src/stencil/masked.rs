//! A square linear operator restricted to the active cells of a [`CellMask`].

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD};

use crate::{CellMask, LinearOperator, OpsError, Result};

/// `A` restricted to the active cells of a mask: with `P` the diagonal projection
/// onto active cells, `M = P A P + (I − P)`.
///
/// Active cells see inactive neighbours as zero (for a Laplacian, an obstacle
/// acts as a zero value at the neighbouring cell centre); inactive cells are
/// decoupled and mapped to themselves, so `M` stays invertible, and symmetric
/// positive definite when `A` is. Adjoint: `Mᵀ = P Aᵀ P + (I − P)`.
#[derive(Debug, Clone)]
pub struct Masked<A> {
    op: A,
    mask: CellMask,
}

impl<A> Masked<A> {
    /// `op` restricted to `mask`. `T` is the scalar whose [`LinearOperator`]
    /// implementation gives the shapes (`Masked::new::<f64>(op, mask)`; the stencils
    /// have the same shapes in every precision).
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if `op` is not square, and
    /// [`OpsError::ShapeMismatch`] if the mask does not have its shape.
    pub fn new<T: Real>(op: A, mask: CellMask) -> Result<Self>
    where
        A: LinearOperator<T>,
    {
        if op.input_shape() != op.output_shape() {
            return Err(OpsError::invalid(
                "masked",
                format!(
                    "{} maps {:?} to {:?}; a mask needs a square operator",
                    op.name(),
                    op.input_shape(),
                    op.output_shape()
                ),
            ));
        }
        if mask.shape() != op.input_shape() {
            return Err(OpsError::shape("masked", op.input_shape(), mask.shape()));
        }
        Ok(Masked { op, mask })
    }

    /// The mask.
    pub fn mask(&self) -> &CellMask {
        &self.mask
    }

    /// The unmasked operator.
    pub fn operator(&self) -> &A {
        &self.op
    }

    /// `out = P B (P x) + (I − P) x` with `B` applied by `apply`.
    fn masked_apply<T: Real>(
        &self,
        x: ArrayViewD<'_, T>,
        mut out: ArrayViewMutD<'_, T>,
        apply: impl FnOnce(ArrayViewD<'_, T>, ArrayViewMutD<'_, T>),
    ) {
        let mut px = x.to_owned();
        self.mask
            .zero_inactive(px.view_mut())
            .expect("shape checked at construction");
        apply(px.view(), out.view_mut());
        for ((o, &xv), &a) in out.iter_mut().zip(x.iter()).zip(self.mask.as_slice()) {
            if !a {
                *o = xv;
            }
        }
    }
}

impl<T: Real, A: LinearOperator<T>> LinearOperator<T> for Masked<A> {
    fn name(&self) -> &str {
        self.op.name()
    }
    fn input_shape(&self) -> &[usize] {
        self.op.input_shape()
    }
    fn output_shape(&self) -> &[usize] {
        self.op.output_shape()
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.masked_apply(x, out, |x, o| self.op.apply_into(x, o));
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.masked_apply(y, out, |y, o| self.op.apply_transpose_into(y, o));
    }
    fn is_symmetric(&self) -> bool {
        self.op.is_symmetric()
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        let mut d = self.op.diagonal()?;
        for (v, &a) in d.iter_mut().zip(self.mask.as_slice()) {
            if !a {
                *v = T::one();
            }
        }
        Some(d)
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let active = self.mask.as_slice();
        let mut t: Vec<_> = self
            .op
            .triplets()?
            .into_iter()
            .filter(|&(r, c, _)| active[r] && active[c])
            .collect();
        t.extend(
            active
                .iter()
                .enumerate()
                .filter(|(_, &a)| !a)
                .map(|(k, _)| (k, k, T::one())),
        );
        Some(t)
    }
}
