//! Selection by a boolean mask (`where`), with broadcasting.

use ndarray::{ArrayD, ArrayViewD, IxDyn, Zip};

use super::broadcast::{broadcast_shape, sum_to_shape_owned};
use crate::{BackwardArgs, Op, Real, Result, Var};

/// `y = mask ? a : b`, the three broadcast together. Keeps the mask.
struct Select {
    mask: ArrayD<bool>,
}

impl<T: Real> Op<T> for Select {
    fn name(&self) -> &str {
        "select"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let (a, b) = (&inputs[0], &inputs[1]);
        let shape = broadcast_shape("select", self.mask.shape(), a.shape())?;
        let shape = IxDyn(&broadcast_shape("select", &shape, b.shape())?);
        let mask = self.mask.broadcast(shape.clone()).expect("shape checked");
        let a = a.broadcast(shape.clone()).expect("shape checked");
        let b = b.broadcast(shape).expect("shape checked");
        Ok(vec![Zip::from(&mask)
            .and(&a)
            .and(&b)
            .map_collect(|&m, &a, &b| if m { a } else { b })])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        let g = args.grad_out();
        let mask = self.mask.broadcast(g.raw_dim()).expect("shape checked");
        // Input 0 takes the gradient where the mask is true, input 1 where it is false.
        let grad_for = |which: usize| {
            let take = which == 0;
            let routed = Zip::from(&mask)
                .and(g)
                .map_collect(|&m, &g| if m == take { g } else { T::zero() });
            sum_to_shape_owned(routed, args.input(which).shape())
        };
        Ok(vec![
            args.needs(0).then(|| grad_for(0)),
            args.needs(1).then(|| grad_for(1)),
        ])
    }

    fn saved_bytes(&self) -> usize {
        self.mask.len() * std::mem::size_of::<bool>()
    }
}

impl<'t, T: Real> Var<'t, T> {
    /// `y = mask ? on_true : on_false` elementwise, with `mask`, `on_true` and
    /// `on_false` broadcast together (NumPy `where`). Adjoint: the incoming gradient
    /// routed to `on_true` where the mask is true and to `on_false` where it is
    /// false, each summed back to its input's shape.
    ///
    /// # Errors
    /// [`crate::TapeError::ShapeMismatch`] naming `select` if the three shapes do
    /// not broadcast; [`crate::TapeError::ForeignVar`] if the two values are on
    /// different tapes.
    pub fn select(
        mask: &ArrayD<bool>,
        on_true: Var<'t, T>,
        on_false: Var<'t, T>,
    ) -> Result<Var<'t, T>> {
        on_true
            .tape
            .apply(Select { mask: mask.clone() }, &[on_true, on_false])
    }
}
