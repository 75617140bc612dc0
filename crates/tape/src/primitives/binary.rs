//! Elementwise binary ops with broadcasting: add, sub, mul, div, min, max.
//!
//! Each is a kernel `f(a, b)` and its partial derivatives `df(a, b, y) -> (∂y/∂a, ∂y/∂b)`;
//! one generic op does the broadcasting in the forward and sums gradients back to
//! each input's shape in the backward.

use ndarray::{ArrayD, ArrayViewD, IxDyn, Zip};

use super::broadcast::{broadcast_shape, sum_to_shape_owned};
use crate::{parallel, BackwardArgs, Op, Real, Result, Var};

/// The maths of one elementwise binary op.
pub(crate) trait BinaryKernel<T: Real>: Copy + 'static {
    const NAME: &'static str;
    /// `y = f(a, b)`.
    fn f(a: T, b: T) -> T;
    /// `(∂y/∂a, ∂y/∂b)` at `(a, b)` with `y = f(a, b)`.
    fn df(a: T, b: T, y: T) -> (T, T);
}

#[derive(Clone, Copy)]
pub(crate) struct Binary<K>(pub(crate) K);

impl<T: Real, K: BinaryKernel<T>> Op<T> for Binary<K> {
    fn name(&self) -> &str {
        K::NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let (a, b) = (&inputs[0], &inputs[1]);
        let shape = broadcast_shape(K::NAME, a.shape(), b.shape())?;
        if let Some(y) = forward_contiguous::<T, K>(a, b, &shape) {
            return Ok(vec![y]);
        }
        let a = a.broadcast(IxDyn(&shape)).expect("shape checked");
        let b = b.broadcast(IxDyn(&shape)).expect("shape checked");
        Ok(vec![Zip::from(&a).and(&b).map_collect(|&a, &b| K::f(a, b))])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        if let Some(grads) = backward_contiguous::<T, K>(args) {
            return Ok(grads);
        }
        let y = args.output(0);
        let a = args.input(0).broadcast(y.raw_dim()).expect("shape checked");
        let b = args.input(1).broadcast(y.raw_dim()).expect("shape checked");
        let g = args.grad_out();
        let grad_for = |which: usize| {
            let full = Zip::from(&a)
                .and(&b)
                .and(y)
                .and(g)
                .map_collect(|&a, &b, &y, &g| {
                    let (da, db) = K::df(a, b, y);
                    g * if which == 0 { da } else { db }
                });
            sum_to_shape_owned(full, args.input(which).shape())
        };
        Ok(vec![
            args.needs(0).then(|| grad_for(0)),
            args.needs(1).then(|| grad_for(1)),
        ])
    }
}

/// An operand of the contiguous fast path: a whole array in row-major order, or
/// a single value broadcast to every element.
#[derive(Clone, Copy)]
enum Operand<'a, T> {
    Full(&'a [T]),
    Scalar(T),
}

impl<'a, T: Real> Operand<'a, T> {
    /// `x` as an operand of an output with `len` elements, if it is one.
    fn of(x: &'a ArrayViewD<'_, T>, len: usize) -> Option<Self> {
        if x.len() == 1 && len != 1 {
            return x.first().map(|&v| Operand::Scalar(v));
        }
        if x.len() == len && x.is_standard_layout() {
            return x.to_slice().map(Operand::Full);
        }
        None
    }

    #[inline(always)]
    fn at(&self, i: usize) -> T {
        match self {
            Operand::Full(s) => s[i],
            Operand::Scalar(v) => *v,
        }
    }
}

/// The forward on contiguous operands of the output's size (or single values),
/// into a pooled buffer, chunked over all cores; `None` for other layouts.
fn forward_contiguous<T: Real, K: BinaryKernel<T>>(
    a: &ArrayViewD<'_, T>,
    b: &ArrayViewD<'_, T>,
    shape: &[usize],
) -> Option<ArrayD<T>> {
    let len: usize = shape.iter().product();
    if len < crate::pool::MIN_POOLED_LEN {
        return None;
    }
    let (a, b) = (Operand::of(a, len)?, Operand::of(b, len)?);
    let mut y = crate::pool::take_array::<T>(shape);
    let out = y.as_slice_mut().expect("pooled arrays are contiguous");
    parallel::for_each_chunk_mut(out, |off, o| match (a, b) {
        (Operand::Full(a), Operand::Full(b)) => {
            let r = off..off + o.len();
            for ((o, &a), &b) in o.iter_mut().zip(&a[r.clone()]).zip(&b[r]) {
                *o = K::f(a, b);
            }
        }
        (Operand::Full(a), Operand::Scalar(b)) => {
            let n = o.len();
            for (o, &a) in o.iter_mut().zip(&a[off..off + n]) {
                *o = K::f(a, b);
            }
        }
        _ => {
            for (i, o) in o.iter_mut().enumerate() {
                *o = K::f(a.at(off + i), b.at(off + i));
            }
        }
    });
    Some(y)
}

/// `sink(i, g_i · ∂y_i/∂input_W)` for the elements `off..off + ys.len()`, one
/// loop per operand layout so that each compiles without a branch inside.
#[inline(always)]
fn partials<T: Real, K: BinaryKernel<T>, const W: usize>(
    a: Operand<'_, T>,
    b: Operand<'_, T>,
    off: usize,
    ys: &[T],
    gs: &[T],
    mut sink: impl FnMut(usize, T),
) {
    let pick = |(da, db): (T, T)| if W == 0 { da } else { db };
    let n = ys.len();
    match (a, b) {
        (Operand::Full(a), Operand::Full(b)) => {
            let (a, b) = (&a[off..off + n], &b[off..off + n]);
            for i in 0..n {
                sink(i, gs[i] * pick(K::df(a[i], b[i], ys[i])));
            }
        }
        (Operand::Full(a), Operand::Scalar(b)) => {
            let a = &a[off..off + n];
            for i in 0..n {
                sink(i, gs[i] * pick(K::df(a[i], b, ys[i])));
            }
        }
        (Operand::Scalar(a), Operand::Full(b)) => {
            let b = &b[off..off + n];
            for i in 0..n {
                sink(i, gs[i] * pick(K::df(a, b[i], ys[i])));
            }
        }
        (Operand::Scalar(a), Operand::Scalar(b)) => {
            for i in 0..n {
                sink(i, gs[i] * pick(K::df(a, b, ys[i])));
            }
        }
    }
}

/// The backward on contiguous operands (see [`forward_contiguous`]): a full
/// input's gradient is mapped into a pooled buffer, a single value's is the
/// chunked (deterministic) sum of its partials; `None` for other layouts.
fn backward_contiguous<T: Real, K: BinaryKernel<T>>(
    args: &BackwardArgs<'_, T>,
) -> Option<Vec<Option<ArrayD<T>>>> {
    let y = args.output(0);
    let len = y.len();
    if len < crate::pool::MIN_POOLED_LEN {
        return None;
    }
    let a = Operand::of(args.input(0), len)?;
    let b = Operand::of(args.input(1), len)?;
    let ys = y.as_slice()?;
    let gs = args.grad_out().as_slice()?;
    if !(y.is_standard_layout() && args.grad_out().is_standard_layout()) {
        return None;
    }
    let grad_for = |which: usize, x: Operand<'_, T>| -> ArrayD<T> {
        match x {
            Operand::Full(_) => {
                let mut g = crate::pool::take_array::<T>(y.shape());
                let out = g.as_slice_mut().expect("pooled arrays are contiguous");
                parallel::for_each_chunk_mut(out, |off, o| {
                    let r = off..off + o.len();
                    let (ys, gs) = (&ys[r.clone()], &gs[r]);
                    if which == 0 {
                        partials::<T, K, 0>(a, b, off, ys, gs, |i, v| o[i] = v);
                    } else {
                        partials::<T, K, 1>(a, b, off, ys, gs, |i, v| o[i] = v);
                    }
                });
                g
            }
            Operand::Scalar(_) => {
                let sum = parallel::map_chunks(len, |r| {
                    let off = r.start;
                    let (ys, gs) = (&ys[r.clone()], &gs[r]);
                    let mut acc = T::zero();
                    if which == 0 {
                        partials::<T, K, 0>(a, b, off, ys, gs, |_, v| acc += v);
                    } else {
                        partials::<T, K, 1>(a, b, off, ys, gs, |_, v| acc += v);
                    }
                    acc
                })
                .into_iter()
                .fold(T::zero(), |s, p| s + p);
                ArrayD::from_elem(args.input(which).shape(), sum)
            }
        }
    };
    Some(vec![
        args.needs(0).then(|| grad_for(0, a)),
        args.needs(1).then(|| grad_for(1, b)),
    ])
}

macro_rules! binary_kernel {
    ($(#[$doc:meta])* $kernel:ident, $name:literal, |$a:ident, $b:ident| $f:expr, |$da:ident, $db:ident, $y:ident| $df:expr) => {
        $(#[$doc])*
        #[derive(Clone, Copy)]
        pub(crate) struct $kernel;
        impl<T: Real> BinaryKernel<T> for $kernel {
            const NAME: &'static str = $name;
            #[inline]
            fn f($a: T, $b: T) -> T {
                $f
            }
            #[inline]
            #[allow(unused_variables)]
            fn df($da: T, $db: T, $y: T) -> (T, T) {
                $df
            }
        }
    };
}

binary_kernel!(Add, "add", |a, b| a + b, |a, b, y| (T::one(), T::one()));
binary_kernel!(Sub, "sub", |a, b| a - b, |a, b, y| (T::one(), -T::one()));
binary_kernel!(Mul, "mul", |a, b| a * b, |a, b, y| (b, a));
// d(a/b)/da = 1/b, d(a/b)/db = -a/b² = -y/b
binary_kernel!(Div, "div", |a, b| a / b, |a, b, y| (T::one() / b, -y / b));
// Ties send the whole gradient to the first input (a subgradient).
binary_kernel!(
    Minimum,
    "minimum",
    |a, b| if a <= b { a } else { b },
    |a, b, y| {
        if a <= b {
            (T::one(), T::zero())
        } else {
            (T::zero(), T::one())
        }
    }
);
binary_kernel!(
    Maximum,
    "maximum",
    |a, b| if a >= b { a } else { b },
    |a, b, y| {
        if a >= b {
            (T::one(), T::zero())
        } else {
            (T::zero(), T::one())
        }
    }
);

// The names are the mathematics; the std operator traits cannot return a Result.
#[allow(clippy::should_implement_trait)]
impl<'t, T: Real> Var<'t, T> {
    /// `self + rhs`, broadcasting. Adjoint: `grad` summed to each input's shape.
    ///
    /// # Errors
    /// [`crate::TapeError::ShapeMismatch`] if the shapes do not broadcast;
    /// [`crate::TapeError::ForeignVar`] if `rhs` is on another tape.
    pub fn add(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Add), &[self, rhs])
    }

    /// `self − rhs`, broadcasting. Adjoint: `(grad, −grad)`, summed to shape.
    ///
    /// # Errors
    /// As [`Var::add`].
    pub fn sub(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Sub), &[self, rhs])
    }

    /// `self · rhs` elementwise, broadcasting. Adjoint: `(grad·rhs, grad·self)`.
    ///
    /// # Errors
    /// As [`Var::add`].
    pub fn mul(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Mul), &[self, rhs])
    }

    /// `self / rhs` elementwise, broadcasting. Adjoint: `(grad/rhs, −grad·y/rhs)`.
    ///
    /// # Errors
    /// As [`Var::add`]; [`crate::TapeError::NonFinite`] on division by zero.
    pub fn div(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Div), &[self, rhs])
    }

    /// Elementwise `min(self, rhs)`, broadcasting. Adjoint: `grad` to the smaller
    /// input (to `self` on ties).
    ///
    /// # Errors
    /// As [`Var::add`].
    pub fn minimum(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Minimum), &[self, rhs])
    }

    /// Elementwise `max(self, rhs)`, broadcasting. Adjoint: `grad` to the larger
    /// input (to `self` on ties).
    ///
    /// # Errors
    /// As [`Var::add`].
    pub fn maximum(self, rhs: Var<'t, T>) -> Result<Var<'t, T>> {
        self.tape.apply(Binary(Maximum), &[self, rhs])
    }
}
