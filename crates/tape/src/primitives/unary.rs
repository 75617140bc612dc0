//! Elementwise unary ops: neg, scalar add/mul, powi, exp, ln, sqrt, sin, cos, tanh,
//! relu, sigmoid, abs.
//!
//! Each is a kernel `f(x)` and its derivative `df(x, y) = dy/dx` (given `y = f(x)`,
//! which is cheaper for exp, tanh, sigmoid, sqrt); one generic op maps the kernel
//! over the input and multiplies the incoming gradient by `df` in the backward.

use ndarray::{ArrayD, ArrayViewD, Zip};

use crate::{BackwardArgs, Op, Real, Result, Var};

/// The maths of one elementwise unary op.
pub(crate) trait UnaryKernel<T: Real>: Copy + 'static {
    const NAME: &'static str;
    /// `y = f(x)`.
    fn f(&self, x: T) -> T;
    /// `dy/dx` at `x`, with `y = f(x)`.
    fn df(&self, x: T, y: T) -> T;
}

#[derive(Clone, Copy)]
pub(crate) struct Unary<K>(pub(crate) K);

impl<T: Real, K: UnaryKernel<T>> Op<T> for Unary<K> {
    fn name(&self) -> &str {
        K::NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> Result<Vec<ArrayD<T>>> {
        let k = self.0;
        Ok(vec![inputs[0].mapv(|x| k.f(x))])
    }

    fn backward(&self, args: &BackwardArgs<'_, T>) -> Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) {
            return Ok(vec![None]);
        }
        let k = self.0;
        let grad = Zip::from(args.input(0))
            .and(args.output(0))
            .and(args.grad_out())
            .map_collect(|&x, &y, &g| g * k.df(x, y));
        Ok(vec![Some(grad)])
    }
}

macro_rules! unary_kernel {
    ($kernel:ident, $name:literal, |$x:ident| $f:expr, |$dx:ident, $y:ident| $df:expr) => {
        #[derive(Clone, Copy)]
        pub(crate) struct $kernel;
        impl<T: Real> UnaryKernel<T> for $kernel {
            const NAME: &'static str = $name;
            #[inline]
            fn f(&self, $x: T) -> T {
                $f
            }
            #[inline]
            #[allow(unused_variables)]
            fn df(&self, $dx: T, $y: T) -> T {
                $df
            }
        }
    };
}

unary_kernel!(Neg, "neg", |x| -x, |x, y| -T::one());
unary_kernel!(Exp, "exp", |x| x.exp(), |x, y| y);
unary_kernel!(Ln, "ln", |x| x.ln(), |x, y| x.recip());
// d√x/dx = 1/(2√x) = 1/(2y): infinite at 0, which the tape reports.
unary_kernel!(Sqrt, "sqrt", |x| x.sqrt(), |x, y| (y + y).recip());
unary_kernel!(Sin, "sin", |x| x.sin(), |x, y| x.cos());
unary_kernel!(Cos, "cos", |x| x.cos(), |x, y| -x.sin());
unary_kernel!(Tanh, "tanh", |x| x.tanh(), |x, y| T::one() - y * y);
// At the kink the subgradient 0 is taken.
unary_kernel!(
    Relu,
    "relu",
    |x| if x > T::zero() { x } else { T::zero() },
    |x, y| if x > T::zero() { T::one() } else { T::zero() }
);
unary_kernel!(Sigmoid, "sigmoid", |x| sigmoid(x), |x, y| y
    * (T::one() - y));
unary_kernel!(Abs, "abs", |x| x.abs(), |x, y| sign(x));

/// `1/(1 + e^{−x})`, evaluated without overflow for large `|x|`.
fn sigmoid<T: Real>(x: T) -> T {
    if x >= T::zero() {
        (T::one() + (-x).exp()).recip()
    } else {
        let e = x.exp();
        e / (T::one() + e)
    }
}

/// The sign of `x`, with 0 at 0 (the subgradient of `|x|` taken there).
fn sign<T: Real>(x: T) -> T {
    if x > T::zero() {
        T::one()
    } else if x < T::zero() {
        -T::one()
    } else {
        T::zero()
    }
}

/// `y = x + c`.
#[derive(Clone, Copy)]
pub(crate) struct AddScalar<T>(T);

impl<T: Real> UnaryKernel<T> for AddScalar<T> {
    const NAME: &'static str = "add_scalar";
    fn f(&self, x: T) -> T {
        x + self.0
    }
    fn df(&self, _: T, _: T) -> T {
        T::one()
    }
}

/// `y = c·x`.
#[derive(Clone, Copy)]
pub(crate) struct MulScalar<T>(T);

impl<T: Real> UnaryKernel<T> for MulScalar<T> {
    const NAME: &'static str = "mul_scalar";
    fn f(&self, x: T) -> T {
        x * self.0
    }
    fn df(&self, _: T, _: T) -> T {
        self.0
    }
}

/// `y = xⁿ`.
#[derive(Clone, Copy)]
pub(crate) struct Powi(i32);

impl<T: Real> UnaryKernel<T> for Powi {
    const NAME: &'static str = "powi";
    fn f(&self, x: T) -> T {
        x.powi(self.0)
    }
    fn df(&self, x: T, _: T) -> T {
        // n·xⁿ⁻¹; for n = 0 the derivative is 0 everywhere (also at x = 0, where
        // 0·x⁻¹ would be NaN).
        match self.0 {
            0 => T::zero(),
            n => T::from_f64(f64::from(n)) * x.powi(n - 1),
        }
    }
}

// The names are the mathematics; std::ops::Neg cannot return a Result.
#[allow(clippy::should_implement_trait)]
impl<'t, T: Real> Var<'t, T> {
    fn unary<K: UnaryKernel<T>>(self, kernel: K) -> Result<Var<'t, T>> {
        self.tape.apply(Unary(kernel), &[self])
    }

    /// `y = −x`. Adjoint: `grad_x = −grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only if the input already holds NaN or infinity.
    pub fn neg(self) -> Result<Var<'t, T>> {
        self.unary(Neg)
    }

    /// `y = x + c`. Adjoint: `grad_x = grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] on overflow.
    pub fn add_scalar(self, c: T) -> Result<Var<'t, T>> {
        self.unary(AddScalar(c))
    }

    /// `y = c·x`. Adjoint: `grad_x = c·grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] on overflow.
    pub fn mul_scalar(self, c: T) -> Result<Var<'t, T>> {
        self.unary(MulScalar(c))
    }

    /// `y = xⁿ` for an integer `n`. Adjoint: `grad_x = n·xⁿ⁻¹·grad_y` (0 for `n = 0`).
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] for `x = 0` with `n < 0`, and on overflow.
    pub fn powi(self, n: i32) -> Result<Var<'t, T>> {
        self.unary(Powi(n))
    }

    /// `y = eˣ`. Adjoint: `grad_x = y·grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] on overflow.
    pub fn exp(self) -> Result<Var<'t, T>> {
        self.unary(Exp)
    }

    /// `y = ln x`. Adjoint: `grad_x = grad_y / x`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] naming `ln` for `x ≤ 0` (NaN or −∞ in the
    /// forward), while the tape checks values.
    pub fn ln(self) -> Result<Var<'t, T>> {
        self.unary(Ln)
    }

    /// `y = √x`. Adjoint: `grad_x = grad_y / (2y)`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] naming `sqrt` for `x < 0` (forward) and for
    /// `x = 0` in the backward, where the derivative is infinite.
    pub fn sqrt(self) -> Result<Var<'t, T>> {
        self.unary(Sqrt)
    }

    /// `y = sin x`. Adjoint: `grad_x = cos x · grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only for an infinite input.
    pub fn sin(self) -> Result<Var<'t, T>> {
        self.unary(Sin)
    }

    /// `y = cos x`. Adjoint: `grad_x = −sin x · grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only for an infinite input.
    pub fn cos(self) -> Result<Var<'t, T>> {
        self.unary(Cos)
    }

    /// `y = tanh x`. Adjoint: `grad_x = (1 − y²)·grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only if the input holds NaN.
    pub fn tanh(self) -> Result<Var<'t, T>> {
        self.unary(Tanh)
    }

    /// `y = max(x, 0)`. Adjoint: `grad_x = grad_y` where `x > 0`, else 0 (the
    /// subgradient 0 at the kink).
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only if the input holds NaN or infinity.
    pub fn relu(self) -> Result<Var<'t, T>> {
        self.unary(Relu)
    }

    /// `y = 1/(1 + e^{−x})`, evaluated without overflow. Adjoint:
    /// `grad_x = y(1 − y)·grad_y`.
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only if the input holds NaN.
    pub fn sigmoid(self) -> Result<Var<'t, T>> {
        self.unary(Sigmoid)
    }

    /// `y = |x|`. Adjoint: `grad_x = sign(x)·grad_y` (the subgradient 0 at `x = 0`).
    ///
    /// # Errors
    /// [`crate::TapeError::NonFinite`] only if the input holds NaN or infinity.
    pub fn abs(self) -> Result<Var<'t, T>> {
        self.unary(Abs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigmoid_does_not_overflow() {
        assert_eq!(sigmoid(-1000.0_f64), 0.0);
        assert_eq!(sigmoid(1000.0_f64), 1.0);
        assert!((sigmoid(0.3_f64) - 1.0 / (1.0 + (-0.3_f64).exp())).abs() < 1e-16);
    }

    #[test]
    fn powi_derivative_is_zero_for_n_zero() {
        assert_eq!(Powi(0).df(0.0_f64, 1.0), 0.0);
        assert_eq!(Powi(1).df(0.0_f64, 0.0), 1.0);
        assert_eq!(Powi(3).df(2.0_f64, 8.0), 12.0); // 3·2²
    }
}
