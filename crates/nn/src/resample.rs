//! Resampling by a factor of two along the spatial axes of `[batch, channels, n]`
//! or `[batch, channels, height, width]` fields: average pooling (coarsen) and
//! nearest-neighbour upsampling (refine), the two halves of a multi-scale network.
//!
//! With `m` the number of fine cells per coarse cell (2 in 1D, 4 in 2D) and
//! `I ∈ block(i)` the fine cells of coarse cell `i`:
//!
//! - average pooling `y[i] = (1/m) Σ_{I ∈ block(i)} x[I]`, adjoint
//!   `∂L/∂x[I] = (1/m) g[i]` for `I ∈ block(i)`;
//! - upsampling `y[I] = x[i]` for `I ∈ block(i)`, adjoint
//!   `∂L/∂x[i] = Σ_{I ∈ block(i)} g[I]`.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, IxDyn, Op, Real, Result, TapeError};

/// Which way a [`Resample`] goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// 2× average pooling: every spatial size halves (and must be even).
    Pool,
    /// 2× nearest-neighbour upsampling: every spatial size doubles.
    Upsample,
}

/// Planes, height and width of a 3-D or 4-D field (height 1 in 1D).
fn planes(name: &str, shape: &[usize]) -> Result<(usize, usize, usize)> {
    match *shape {
        [b, c, n] => Ok((b * c, 1, n)),
        [b, c, h, w] => Ok((b * c, h, w)),
        _ => Err(TapeError::invalid(
            name,
            format!(
                "input of shape {shape:?}: expected [batch, channels, n] or \
                 [batch, channels, height, width]"
            ),
        )),
    }
}

/// Visits every (coarse index, fine index) pair of a coarse field of
/// `p × h × w` planes and its fine field, in row-major order of the fine one.
fn for_each_pair(rank: usize, (p, h, w): (usize, usize, usize), mut f: impl FnMut(usize, usize)) {
    let fy = if rank == 3 { 1 } else { 2 };
    let (fh, fw) = (h * fy, w * 2);
    for plane in 0..p {
        for yy in 0..fh {
            for xx in 0..fw {
                let coarse = (plane * h + yy / fy) * w + xx / 2;
                let fine = (plane * fh + yy) * fw + xx;
                f(coarse, fine);
            }
        }
    }
}

/// 2× pooling or upsampling on plain arrays; `name` labels errors.
///
/// # Errors
/// [`TapeError::InvalidArgument`] naming `name` if `x` is not 3-D or 4-D, or (for
/// pooling) a spatial size is odd.
pub fn resample_forward<T: Real>(
    name: &str,
    direction: Direction,
    x: ArrayViewD<'_, T>,
) -> Result<ArrayD<T>> {
    let (p, h, w) = planes(name, x.shape())?;
    let rank = x.ndim();
    let x = x.as_standard_layout();
    let xs = x.as_slice().expect("standard layout");
    let mut shape = x.shape().to_vec();
    match direction {
        Direction::Pool => {
            if w % 2 != 0 || (rank == 4 && h % 2 != 0) {
                return Err(TapeError::invalid(
                    name,
                    format!("2× pooling needs even spatial sizes, got shape {shape:?}"),
                ));
            }
            for s in &mut shape[2..] {
                *s /= 2;
            }
            let coarse = (p, if rank == 3 { 1 } else { h / 2 }, w / 2);
            let m = T::from_usize(if rank == 3 { 2 } else { 4 });
            let mut out = vec![T::zero(); xs.len() / if rank == 3 { 2 } else { 4 }];
            for_each_pair(rank, coarse, |c, f| out[c] += xs[f]);
            out.iter_mut().for_each(|v| *v /= m);
            Ok(ArrayD::from_shape_vec(IxDyn(&shape), out).expect("sizes match"))
        }
        Direction::Upsample => {
            for s in &mut shape[2..] {
                *s *= 2;
            }
            let mut out = vec![T::zero(); shape.iter().product()];
            for_each_pair(rank, (p, h, w), |c, f| out[f] = xs[c]);
            Ok(ArrayD::from_shape_vec(IxDyn(&shape), out).expect("sizes match"))
        }
    }
}

/// The adjoint of [`resample_forward`]: maps a gradient of the output's shape to
/// one of `x_shape`.
///
/// # Errors
/// As [`resample_forward`] for `x_shape`, and [`TapeError::ShapeMismatch`] if
/// `grad_y` does not have the shape the forward gives `x_shape`.
pub fn resample_adjoint<T: Real>(
    name: &str,
    direction: Direction,
    grad_y: ArrayViewD<'_, T>,
    x_shape: &[usize],
) -> Result<ArrayD<T>> {
    let (p, h, w) = planes(name, x_shape)?;
    let rank = x_shape.len();
    let mut y_shape = x_shape.to_vec();
    match direction {
        Direction::Pool => {
            if w % 2 != 0 || (rank == 4 && h % 2 != 0) {
                return Err(TapeError::invalid(
                    name,
                    format!("2× pooling needs even spatial sizes, got shape {x_shape:?}"),
                ));
            }
            y_shape[2..].iter_mut().for_each(|s| *s /= 2);
        }
        Direction::Upsample => y_shape[2..].iter_mut().for_each(|s| *s *= 2),
    }
    if grad_y.shape() != y_shape.as_slice() {
        return Err(TapeError::shape(
            &format!("{name} adjoint"),
            &y_shape,
            grad_y.shape(),
        ));
    }
    let g = grad_y.as_standard_layout();
    let gs = g.as_slice().expect("standard layout");
    let mut out = vec![T::zero(); x_shape.iter().product()];
    match direction {
        Direction::Pool => {
            let coarse = (p, if rank == 3 { 1 } else { h / 2 }, w / 2);
            let m = T::from_usize(if rank == 3 { 2 } else { 4 });
            for_each_pair(rank, coarse, |c, f| out[f] = gs[c] / m);
        }
        Direction::Upsample => for_each_pair(rank, (p, h, w), |c, f| out[c] += gs[f]),
    }
    Ok(ArrayD::from_shape_vec(IxDyn(x_shape), out).expect("sizes match"))
}

/// 2× pooling or upsampling as a tape op; see the module docs.
#[derive(Debug, Clone)]
pub struct Resample {
    /// Names the op in errors.
    pub name: String,
    /// Pool or upsample.
    pub direction: Direction,
}

impl<T: Real> Op<T> for Resample {
    fn name(&self) -> &str {
        &self.name
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(&self.name, 1, inputs.len())?;
        Ok(vec![resample_forward(
            &self.name,
            self.direction,
            inputs[0].view(),
        )?])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        Ok(vec![Some(resample_adjoint(
            &self.name,
            self.direction,
            args.grad_out().view(),
            args.input(0).shape(),
        )?)])
    }
}
