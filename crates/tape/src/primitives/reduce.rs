//! Reductions: sum of all elements, sum along an axis, mean, and the full
//! contraction (dot) of two tensors.

use ndarray::{ArrayD, ArrayViewD, Axis, IxDyn, Zip};

use super::check_axis;
use super::linear::{Linear, LinearMap};
use crate::{parallel, BackwardArgs, Op, Real, Result, TapeError, Var};

/// `y = Σᵢ xᵢ` (0-d). Adjoint: `grad_x = grad_y` broadcast to x's shape.
struct Sum;

impl<T: Real> LinearMap<T> for Sum {
    const NAME: &'static str = "sum";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        Ok(ArrayD::from_elem(IxDyn(&[]), sum_of(&x)))
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        filled(x_shape, scalar_of(&grad))
    }
}

/// `y = Σᵢ xᵢ / n` (0-d). Adjoint: `grad_x = grad_y / n` broadcast to x's shape.
struct Mean;

impl<T: Real> LinearMap<T> for Mean {
    const NAME: &'static str = "mean";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        if x.is_empty() {
            return Err(TapeError::invalid(
                "mean",
                format!("mean of an empty array of shape {:?}", x.shape()),
            ));
        }
        let n = T::from_usize(x.len());
        Ok(ArrayD::from_elem(IxDyn(&[]), sum_of(&x) / n))
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        let n = T::from_usize(x_shape.iter().product());
        filled(x_shape, scalar_of(&grad) / n)
    }
}

/// `y[.., j, ..] = Σₖ x[.., k, j, ..]` summing out `axis`. Adjoint: `grad_y`
/// with the axis re-inserted and broadcast along it.
struct SumAxis {
    axis: usize,
}

impl<T: Real> LinearMap<T> for SumAxis {
    const NAME: &'static str = "sum_axis";

    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>> {
        check_axis("sum_axis", self.axis, x.shape())?;
        Ok(x.sum_axis(Axis(self.axis)))
    }

    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T> {
        grad.insert_axis(Axis(self.axis))
            .broadcast(x_shape)
            .expect("the summed axis broadcasts back")
            .to_owned()
    }
}

/// `Σ x`, chunked over all cores (deterministic) when `x` is contiguous.
fn sum_of<T: Real>(x: &ArrayViewD<'_, T>) -> T {
    match x.as_slice_memory_order() {
        Some(s) => parallel::sum_in(s),
        None => x.sum(),
    }
}

/// An array of `shape` holding `v` everywhere, from the buffer pool.
fn filled<T: Real>(shape: &[usize], v: T) -> ArrayD<T> {
    let mut a = crate::pool::take_array::<T>(shape);
    let s = a.as_slice_mut().expect("pooled arrays are contiguous");
    parallel::for_each_chunk_mut(s, |_, o| o.fill(v));
    a
}

/// The single value of a 0-d gradient.
fn scalar_of<T: Real>(grad: &ArrayViewD<'_, T>) -> T {
    grad.first().copied().unwrap_or_else(T::zero)
}

/// `y = Σᵢ aᵢ bᵢ` over two tensors of the same shape (0-d).
/// Adjoint: `grad_a = grad_y·b`, `grad_b = grad_y·a`.
struct Dot;

impl<T: Real> Op<T> for Dot {
    fn name(&self) -> &str {
        "dot"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let (a, b) = (&inputs[0], &inputs[1]);
        if a.shape() != b.shape() {
            return Err(TapeError::shape("dot", a.shape(), b.shape()));
        }
        let y = match (a.as_slice(), b.as_slice()) {
            (Some(a), Some(b)) => parallel::dot_in(a, b),
            _ => Zip::from(a)
                .and(b)
                .fold(T::zero(), |acc, &a, &b| acc + a * b),
        };
        Ok(vec![ArrayD::from_elem(IxDyn(&[]), y)])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let g = scalar_of(args.grad_out());
        let scaled = |which: usize| {
            let other = args.input(1 - which);
            match other.as_slice() {
                Some(x) if x.len() >= crate::pool::MIN_POOLED_LEN => {
                    let mut out = crate::pool::take_array::<T>(other.shape());
                    let o = out.as_slice_mut().expect("pooled arrays are contiguous");
                    parallel::map_into(x, o, |v| v * g);
                    out
                }
                _ => other.mapv(|v| v * g),
            }
        };
        Ok(vec![
            args.needs(0).then(|| scaled(0)),
            args.needs(1).then(|| scaled(1)),
        ])
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// The sum of all elements, a 0-d value: `y = Σᵢ xᵢ`. Adjoint: the incoming
    /// gradient copied to every element.
    ///
    /// # Errors
    /// Only [`crate::TapeError::NonFinite`] if the sum overflows.
    pub fn sum(self) -> Result<Var<'t, T>> {
        self.tape.apply(Linear(Sum), &[self])
    }

    /// The sum along `axis`, which is removed from the shape:
    /// `y[i₀‥, i₊‥] = Σₖ x[i₀‥, k, i₊‥]`. Adjoint: the incoming gradient copied
    /// along the summed axis.
    ///
    /// # Errors
    /// [`crate::TapeError::InvalidArgument`] naming `sum_axis` if `axis` is not an
    /// axis of the value.
    pub fn sum_axis(self, axis: usize) -> Result<Var<'t, T>> {
        self.tape.apply(Linear(SumAxis { axis }), &[self])
    }

    /// The mean of all elements, a 0-d value: `y = Σᵢ xᵢ / n`. Adjoint:
    /// `grad_x = grad_y / n` in every element.
    ///
    /// # Errors
    /// [`crate::TapeError::InvalidArgument`] naming `mean` for an empty value.
    pub fn mean(self) -> Result<Var<'t, T>> {
        self.tape.apply(Linear(Mean), &[self])
    }

    /// The full contraction of two values of the same shape, a 0-d value:
    /// `y = Σᵢ aᵢ bᵢ`. Adjoint: `grad_a = grad_y·b`, `grad_b = grad_y·a`.
    ///
    /// # Errors
    /// [`crate::TapeError::ShapeMismatch`] naming `dot` if the shapes differ (no
    /// broadcasting); [`crate::TapeError::ForeignVar`] if `other` is on another tape.
    pub fn dot(self, other: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Dot, &[self, other])
    }
}

#[cfg(test)]
mod tests {
    use super::super::linear::assert_adjoint;
    use super::*;

    #[test]
    fn reductions_pass_the_dot_product_test() {
        assert_adjoint(&Sum, &[3, 4]);
        assert_adjoint(&Mean, &[3, 4]);
        for axis in 0..3 {
            assert_adjoint(&SumAxis { axis }, &[2, 3, 4]);
        }
    }
}
