//! The dense (fully connected) layer over a batch: `y = x W + b`.
//!
//! Forward, for `x` of shape `[batch, in]`, `W` `[in, out]`, `b` `[out]`:
//! `y[n, o] = b[o] + Σ_i x[n, i] W[i, o]`.
//!
//! Adjoint, with `g = ∂L/∂y`: `∂L/∂x = g Wᵀ`, `∂L/∂W = xᵀ g`,
//! `∂L/∂b[o] = Σ_n g[n, o]`.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, Result, TapeError};
use ndarray::{ArrayView2, Axis, Ix2};

fn matrix<'a, T: Real>(name: &str, what: &str, a: &ArrayViewD<'a, T>) -> Result<ArrayView2<'a, T>> {
    a.clone().into_dimensionality::<Ix2>().map_err(|_| {
        TapeError::invalid(name, format!("{what} of shape {:?} is not 2-D", a.shape()))
    })
}

/// Checks `x` `[batch, in]`, `W` `[in, out]` and `b` `[out]` against each other.
fn check<'a, T: Real>(
    name: &str,
    x: &ArrayViewD<'a, T>,
    w: &ArrayViewD<'a, T>,
    b: Option<&ArrayViewD<'a, T>>,
) -> Result<(ArrayView2<'a, T>, ArrayView2<'a, T>)> {
    let wm = matrix(name, "weight", w)?;
    let xm = matrix(name, "input [batch, features]", x)?;
    if xm.ncols() != wm.nrows() {
        return Err(TapeError::shape(
            &format!("{name} input"),
            &[xm.nrows(), wm.nrows()],
            x.shape(),
        ));
    }
    if let Some(b) = b {
        if b.shape() != [wm.ncols()] {
            return Err(TapeError::shape(
                &format!("{name} bias"),
                &[wm.ncols()],
                b.shape(),
            ));
        }
    }
    Ok((xm, wm))
}

/// `y = x W + b` on plain arrays; `name` labels errors.
///
/// # Errors
/// [`TapeError::InvalidArgument`] or [`TapeError::ShapeMismatch`] naming `name` if
/// the shapes do not fit.
pub fn dense_forward<T: Real>(
    name: &str,
    x: ArrayViewD<'_, T>,
    w: ArrayViewD<'_, T>,
    b: ArrayViewD<'_, T>,
) -> Result<ArrayD<T>> {
    let (xm, wm) = check(name, &x, &w, Some(&b))?;
    Ok((xm.dot(&wm) + &b).into_dyn())
}

/// The dense layer as a tape op over `(x, W, b)`; keeps nothing beyond its
/// inputs and output.
#[derive(Debug, Clone)]
pub struct DenseOp {
    /// Names the op (the layer) in errors.
    pub name: String,
}

impl<T: Real> Op<T> for DenseOp {
    fn name(&self) -> &str {
        &self.name
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(&self.name, 3, inputs.len())?;
        Ok(vec![dense_forward(
            &self.name,
            inputs[0].view(),
            inputs[1].view(),
            inputs[2].view(),
        )?])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let (xm, wm) = check(&self.name, args.input(0), args.input(1), None)?;
        let g = matrix(&self.name, "output gradient", args.grad_out())?;
        Ok(vec![
            args.needs(0).then(|| g.dot(&wm.t()).into_dyn()),
            args.needs(1).then(|| xm.t().dot(&g).into_dyn()),
            args.needs(2).then(|| g.sum_axis(Axis(0)).into_dyn()),
        ])
    }
}
