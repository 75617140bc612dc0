//! The scalar trait every numeric routine in diffphys is generic over.

use std::fmt::{Debug, Display};

use ndarray::NdFloat;

/// A floating-point scalar: implemented for `f32` and `f64`.
///
/// Precision is one of the things diffphys studies, so every tensor, op, solver and
/// optimizer is generic over `Real`. It adds to ndarray's [`NdFloat`] (which brings
/// `num_traits::Float` and the arithmetic ndarray needs) lossless-where-possible
/// conversions to and from `f64` and a few constants.
pub trait Real: NdFloat + Default + Display + Debug + Send + Sync + 'static {
    /// `"f32"` or `"f64"`, for reports.
    const NAME: &'static str;
    /// Machine epsilon of the type.
    const EPS: Self;

    /// Converts from `f64`, rounding to nearest for `f32`.
    fn from_f64(x: f64) -> Self;
    /// Converts to `f64` (exact for both types). Named `as_f64` so that it does not
    /// clash with `num_traits::ToPrimitive::to_f64`, which returns an `Option`.
    fn as_f64(self) -> f64;
    /// Converts a `usize` (rounded for large values).
    #[inline]
    fn from_usize(n: usize) -> Self {
        Self::from_f64(n as f64)
    }
    /// The central finite-difference step suited to this precision, relative to the
    /// magnitude of the perturbed value: `ε^(1/3)`, which balances the `O(h²)`
    /// truncation error against the `O(ε/h)` rounding error.
    fn fd_step() -> Self {
        Self::EPS.cbrt()
    }
    /// The member of a [`PerPrecision`] family for this precision: `single` for
    /// `f32`, `double` for `f64`. Generic code that holds one value per precision
    /// takes its own with it, typed, where it would otherwise downcast through
    /// `std::any::Any`.
    fn pick<F: PerPrecision>(single: F::Of<f32>, double: F::Of<f64>) -> F::Of<Self>;
}

/// A family of types with one member per precision, `Of<f32>` and `Of<f64>`
/// (for example `&dyn Preconditioner<T>`, or `fn(&[T]) -> R`), from which
/// [`Real::pick`] selects the member of a generic `T`.
///
/// ```
/// use diffphys_tape::{PerPrecision, Real};
///
/// /// `fn(T) -> &str`, one function per precision.
/// struct Describe;
/// impl PerPrecision for Describe {
///     type Of<T: Real> = fn(T) -> &'static str;
/// }
/// fn describe<T: Real>(x: T) -> &'static str {
///     T::pick::<Describe>(|_| "single", |_| "double")(x)
/// }
/// assert_eq!((describe(1.0f32), describe(1.0f64)), ("single", "double"));
/// ```
pub trait PerPrecision {
    /// The member for precision `T`.
    type Of<T: Real>;
}

impl Real for f32 {
    const NAME: &'static str = "f32";
    const EPS: Self = f32::EPSILON;
    #[inline]
    fn from_f64(x: f64) -> Self {
        x as f32
    }
    #[inline]
    fn as_f64(self) -> f64 {
        f64::from(self)
    }
    #[inline]
    fn pick<F: PerPrecision>(single: F::Of<f32>, _: F::Of<f64>) -> F::Of<f32> {
        single
    }
}

impl Real for f64 {
    const NAME: &'static str = "f64";
    const EPS: Self = f64::EPSILON;
    #[inline]
    fn from_f64(x: f64) -> Self {
        x
    }
    #[inline]
    fn as_f64(self) -> f64 {
        self
    }
    #[inline]
    fn pick<F: PerPrecision>(_: F::Of<f32>, double: F::Of<f64>) -> F::Of<f64> {
        double
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fd_step_is_cube_root_of_epsilon() {
        assert!((f64::fd_step() - 6.055e-6).abs() < 1e-8);
        assert!((f32::fd_step() - 4.92e-3).abs() < 1e-4);
    }

    #[test]
    fn conversions_round_trip() {
        assert_eq!(f32::from_f64(0.5).as_f64(), 0.5);
        assert_eq!(f64::from_usize(7), 7.0);
        assert_eq!(<f32 as Real>::NAME, "f32");
    }
}
