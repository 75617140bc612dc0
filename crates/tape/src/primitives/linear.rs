//! Linear maps of one input (sums, reshapes, shifts, pads, …): a forward `y = A x`
//! and its adjoint `grad_x = Aᵀ grad_y`, behind one generic op.
//!
//! Because the map is linear its adjoint needs neither the input nor the output
//! values, only the input's shape; each map's body is only that maths.

use ndarray::{ArrayD, ArrayViewD};

use crate::{BackwardArgs, Op, Real, Result};

/// The maths of one linear map of a single input.
pub(crate) trait LinearMap<T: Real>: 'static {
    const NAME: &'static str;
    /// `y = A x`; rejects arguments (axes, bounds, shapes) that do not fit `x`.
    fn forward(&self, x: ArrayViewD<'_, T>) -> Result<ArrayD<T>>;
    /// `Aᵀ grad` for an input of shape `x_shape` (already validated by the forward).
    fn adjoint(&self, grad: ArrayViewD<'_, T>, x_shape: &[usize]) -> ArrayD<T>;
}

/// The op of a [`LinearMap`].
pub(crate) struct Linear<M>(pub(crate) M);

impl<T: Real, M: LinearMap<T>> Op<T> for Linear<M> {
    fn name(&self) -> &str {
        M::NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        Ok(vec![self.0.forward(inputs[0].view())?])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let x_shape = args.input(0).shape();
        Ok(vec![args
            .needs(0)
            .then(|| self.0.adjoint(args.grad_out().view(), x_shape))])
    }
}

/// The dot-product test `<A x, y> = <x, Aᵀ y>` of a map at an input shape.
#[cfg(test)]
pub(crate) fn assert_adjoint<M: LinearMap<f64>>(map: &M, x_shape: &[usize]) {
    use crate::{check_adjoint, test_array};
    let x = test_array::<f64>(x_shape, 11);
    let y_shape = map.forward(x.view()).expect("valid map").shape().to_vec();
    let y = test_array::<f64>(&y_shape, 12);
    let report = check_adjoint(
        |v| map.forward(v).expect("valid map"),
        |g| map.adjoint(g, x_shape),
        x.view(),
        y.view(),
    )
    .expect("shapes agree");
    assert!(report.passes(1e-13), "{}: {report:?}", M::NAME);
}
