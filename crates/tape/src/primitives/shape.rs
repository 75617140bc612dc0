//! Shape ops: reshape, broadcast to a shape, slice, periodic roll, zero padding
//! along an axis, and concatenation. All are linear; the stencil operators are
//! sums of shifted and sliced copies of a field built from them.

use ndarray::{ArrayD, ArrayViewD, Axis, IxDyn, Slice};

use super::broadcast::sum_to_shape;
use super::check_axis;
use super::linear::{Linear, LinearMap};
use crate::{BackwardArgs, Op, Real, Result, TapeError, Var};

/// `y` = the elements of `x` in row-major order, in a new shape of the same size.
/// Adjoint: `grad_y` reshaped back to x's shape.
struct Reshape {
    shape: Vec<usize>,
}

impl<T: Real> LinearMap<T> for Reshape {
    const NAME: &'static str = "reshape";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        let len = self
            .shape
            .iter()
            .try_fold(1_usize, |acc, &n| acc.checked_mul(n));
        if len != Some(x.len()) {
            return Err(TapeError::shape("reshape", x.shape(), &self.shape));
        }
        let y = x
            .to_shape(IxDyn(&self.shape))
            .map_err(|_| TapeError::shape("reshape", x.shape(), &self.shape))?;
        Ok(y.into_owned())
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        grad.to_shape(IxDyn(x_shape))
            .expect("sizes checked in the forward")
            .into_owned()
    }
}

/// `y` = `x` broadcast to `shape` (NumPy rules). Adjoint: `grad_y` summed over the
/// broadcast axes.
struct BroadcastTo {
    shape: Vec<usize>,
}

impl<T: Real> LinearMap<T> for BroadcastTo {
    const NAME: &'static str = "broadcast_to";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        match x.broadcast(IxDyn(&self.shape)) {
            Some(y) => Ok(y.to_owned()),
            None => Err(TapeError::shape("broadcast_to", x.shape(), &self.shape)),
        }
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        sum_to_shape(grad, x_shape)
    }
}

/// `y = x[.., start..end, ..]` along `axis`. Adjoint: `grad_y` placed in a zero
/// array of x's shape.
struct SliceAxis {
    axis: usize,
    start: usize,
    end: usize,
}

impl SliceAxis {
    fn range(&self) -> Slice {
        Slice::from(self.start..self.end)
    }
}

impl<T: Real> LinearMap<T> for SliceAxis {
    const NAME: &'static str = "slice";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        check_axis("slice", self.axis, x.shape())?;
        let n = x.len_of(Axis(self.axis));
        if self.start > self.end || self.end > n {
            return Err(TapeError::invalid(
                "slice",
                format!(
                    "range {}..{} is out of bounds for axis {} of length {n} (shape {:?})",
                    self.start,
                    self.end,
                    self.axis,
                    x.shape()
                ),
            ));
        }
        Ok(x.slice_axis(Axis(self.axis), self.range()).to_owned())
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        let mut g = ArrayD::zeros(x_shape);
        g.slice_axis_mut(Axis(self.axis), self.range())
            .assign(&grad);
        g
    }
}

/// `y[i] = x[(i − shift) mod n]` along `axis` (NumPy `roll`). Adjoint: the roll by
/// `−shift`.
struct Roll {
    shift: isize,
    axis: usize,
}

impl Roll {
    /// The shift reduced to `[0, n)`.
    fn shift_in(&self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            // n fits in isize: no array holds more than isize::MAX bytes.
            self.shift.rem_euclid(n as isize) as usize
        }
    }
}

/// `x` rolled forward by `s ∈ [0, n)` along `axis`: two slice copies, no modulo per
/// element.
fn roll_by<T: Real>(x: ArrayViewD<'_, T>, s: usize, axis: Axis) -> ArrayD<T> {
    let n = x.len_of(axis);
    let mut y = ArrayD::zeros(x.raw_dim());
    y.slice_axis_mut(axis, Slice::from(s..))
        .assign(&x.slice_axis(axis, Slice::from(..n - s)));
    y.slice_axis_mut(axis, Slice::from(..s))
        .assign(&x.slice_axis(axis, Slice::from(n - s..)));
    y
}

impl<T: Real> LinearMap<T> for Roll {
    const NAME: &'static str = "roll";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        check_axis("roll", self.axis, x.shape())?;
        let s = self.shift_in(x.len_of(Axis(self.axis)));
        Ok(roll_by(x, s, Axis(self.axis)))
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        let n = x_shape[self.axis];
        let s = self.shift_in(n);
        roll_by(grad, (n - s) % n.max(1), Axis(self.axis))
    }
}

/// `y` = `x` with `before` zeros prepended and `after` zeros appended along `axis`.
/// Adjoint: the slice of `grad_y` where `x` was placed.
struct Pad {
    axis: usize,
    before: usize,
    after: usize,
}

impl Pad {
    fn interior(&self, n: usize) -> Slice {
        Slice::from(self.before..self.before + n)
    }
}

impl<T: Real> LinearMap<T> for Pad {
    const NAME: &'static str = "pad";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        check_axis("pad", self.axis, x.shape())?;
        let axis = Axis(self.axis);
        let n = x.len_of(axis);
        let mut shape = x.shape().to_vec();
        shape[self.axis] = self
            .before
            .checked_add(n)
            .and_then(|m| m.checked_add(self.after))
            .ok_or_else(|| TapeError::invalid("pad", "padded length overflows usize"))?;
        let mut y = ArrayD::zeros(shape);
        y.slice_axis_mut(axis, self.interior(n)).assign(&x);
        Ok(y)
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        let n = x_shape[self.axis];
        grad.slice_axis(Axis(self.axis), self.interior(n))
            .to_owned()
    }
}

/// `y` = the inputs joined along `axis`. Adjoint: `grad_y` cut back into the
/// inputs' extents along `axis`.
struct Concat {
    axis: usize,
}

impl<T: Real> Op<T> for Concat {
    fn name(&self) -> &str {
        "concat"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let Some(first) = inputs.first() else {
            return Err(TapeError::invalid("concat", "needs at least one value"));
        };
        check_axis("concat", self.axis, first.shape())?;
        let axis = Axis(self.axis);
        let off_axis_agrees = |x: &ArrayViewD<'_, T>| {
            x.ndim() == first.ndim()
                && (0..x.ndim()).all(|k| k == self.axis || x.shape()[k] == first.shape()[k])
        };
        if let Some(bad) = inputs.iter().find(|x| !off_axis_agrees(x)) {
            return Err(TapeError::shape("concat", first.shape(), bad.shape()));
        }
        let mut shape = first.shape().to_vec();
        shape[self.axis] = inputs.iter().map(|x| x.len_of(axis)).sum();
        let mut y = ArrayD::zeros(shape);
        let mut start = 0;
        for x in inputs {
            let end = start + x.len_of(axis);
            y.slice_axis_mut(axis, Slice::from(start..end)).assign(x);
            start = end;
        }
        Ok(vec![y])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let axis = Axis(self.axis);
        let g = args.grad_out();
        let mut start = 0;
        Ok(args
            .inputs
            .iter()
            .enumerate()
            .map(|(i, x)| {
                let end = start + x.len_of(axis);
                let range = Slice::from(start..end);
                start = end;
                args.needs(i).then(|| g.slice_axis(axis, range).to_owned())
            })
            .collect())
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// The same elements in row-major order in a new `shape` of the same size.
    /// Adjoint: the gradient reshaped back.
    ///
    /// # Errors
    /// [`TapeError::ShapeMismatch`] naming `reshape` if the sizes differ.
    pub fn reshape(self, shape: &[usize]) -> Result<Var<'t, T>> {
        let shape = shape.to_vec();
        self.tape.apply(Linear(Reshape { shape }), &[self])
    }

    /// The value broadcast to `shape` by NumPy rules (trailing axes aligned, axes
    /// of length 1 stretched, leading axes added). Adjoint: the gradient summed
    /// over the broadcast axes.
    ///
    /// # Errors
    /// [`TapeError::ShapeMismatch`] naming `broadcast_to` if the value does not
    /// broadcast to `shape`.
    pub fn broadcast_to(self, shape: &[usize]) -> Result<Var<'t, T>> {
        let shape = shape.to_vec();
        self.tape.apply(Linear(BroadcastTo { shape }), &[self])
    }

    /// The entries `start..end` along `axis`: `y[.., j, ..] = x[.., start + j, ..]`.
    /// Adjoint: the gradient placed at `start..end` in zeros of the input's shape.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `slice` if `axis` is not an axis or
    /// the range is not within it.
    pub fn slice(self, axis: usize, start: usize, end: usize) -> Result<Var<'t, T>> {
        self.tape
            .apply(Linear(SliceAxis { axis, start, end }), &[self])
    }

    /// The periodic shift along `axis` (NumPy `roll`): `y[i] = x[(i − shift) mod n]`,
    /// so `shift = 1` moves every entry one place up and the last to the front.
    /// Adjoint: the roll of the gradient by `−shift`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `roll` if `axis` is not an axis.
    pub fn roll(self, shift: isize, axis: usize) -> Result<Var<'t, T>> {
        self.tape.apply(Linear(Roll { shift, axis }), &[self])
    }

    /// `before` zeros prepended and `after` zeros appended along `axis`:
    /// `y[.., before + j, ..] = x[.., j, ..]`, zero elsewhere. Adjoint: the slice
    /// `before..before + n` of the gradient.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `pad` if `axis` is not an axis.
    pub fn pad(self, axis: usize, before: usize, after: usize) -> Result<Var<'t, T>> {
        self.tape.apply(
            Linear(Pad {
                axis,
                before,
                after,
            }),
            &[self],
        )
    }

    /// The values joined along `axis`; all other axes must agree. Adjoint: the
    /// gradient cut back into each input's extent along `axis`.
    ///
    /// # Errors
    /// [`TapeError::InvalidArgument`] naming `concat` for an empty list or an
    /// `axis` that is not an axis; [`TapeError::ShapeMismatch`] if the shapes
    /// differ off `axis`; [`TapeError::ForeignVar`] if the values are not all on
    /// one tape.
    pub fn concat(vars: &[Var<'t, T>], axis: usize) -> Result<Var<'t, T>> {
        let Some(first) = vars.first() else {
            return Err(TapeError::invalid("concat", "needs at least one value"));
        };
        first.tape.apply(Concat { axis }, vars)
    }
}

#[cfg(test)]
mod tests {
    use super::super::linear::assert_adjoint;
    use super::*;

    #[test]
    fn shape_ops_pass_the_dot_product_test() {
        assert_adjoint(&Reshape { shape: vec![4, 3] }, &[2, 6]);
        assert_adjoint(
            &BroadcastTo {
                shape: vec![2, 3, 4],
            },
            &[3, 1],
        );
        assert_adjoint(
            &SliceAxis {
                axis: 1,
                start: 1,
                end: 4,
            },
            &[2, 5],
        );
        for shift in [-7, -1, 0, 2, 5, 13] {
            assert_adjoint(&Roll { shift, axis: 1 }, &[3, 5]);
        }
        assert_adjoint(
            &Pad {
                axis: 0,
                before: 2,
                after: 1,
            },
            &[3, 2],
        );
    }

    #[test]
    fn roll_of_an_empty_axis_is_empty() {
        let x = ArrayD::<f64>::zeros(vec![2, 0]);
        let y = LinearMap::<f64>::forward(&Roll { shift: 3, axis: 1 }, x.view()).unwrap();
        assert_eq!(y.shape(), &[2, 0]);
        let g = LinearMap::<f64>::adjoint(&Roll { shift: 3, axis: 1 }, y.view(), &[2, 0]);
        assert_eq!(g.shape(), &[2, 0]);
    }
}
