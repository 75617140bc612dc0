//! The one helper module of the integration tests: tolerances per precision, the
//! f32/f64 test types, seeded fields and assertions on check reports.
//!
//! Use it from a file in `crates/ops/tests/` with `mod common;` and `use common::*;`.
//! A test generic over the precision is written once and run in both:
//!
//! ```ignore
//! fn my_op_runs<T: Real>() { /* … */ }
//! both_precisions!(my_op_runs); // #[test] my_op_runs::f32 and my_op_runs::f64
//! ```

// Each test file uses a different part of this module.
#![allow(dead_code, unused_imports, unused_macros)]

pub use diffphys_tape::{
    check_adjoint, check_gradient, AdjointReport, ArrayD, GradCheckOptions, GradCheckReport, Real,
    Tape, TapeError, Var,
};

use diffphys_ops::LinearOperator;
use diffphys_tape::test_array;
use ndarray::{Array2, ArrayView1, IxDyn};

/// The single precision test type.
pub type F32 = f32;
/// The double precision test type, the one gradient checks run in.
pub type F64 = f64;

/// How close results must be in precision `T`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// For [`check_gradient`] (finite differences lose about a third of the digits
    /// in f64 and half in f32).
    pub grad: GradCheckOptions,
    /// For the dot-product test: `rel_err` of an [`AdjointReport`] (a sum of a few
    /// thousand rounded products).
    pub adjoint: f64,
    /// For two computations of the same values that round differently (a fused op
    /// against its primitive chain, a solver against a direct solve at its
    /// tolerance): relative to the largest magnitude compared.
    pub close: f64,
}

/// The tolerances of precision `T`.
pub fn tol<T: Real>() -> Tolerances {
    if T::EPS.as_f64() < 1e-10 {
        Tolerances {
            grad: GradCheckOptions::for_type::<T>(),
            adjoint: 1e-12,
            close: 1e-10,
        }
    } else {
        Tolerances {
            grad: GradCheckOptions::for_type::<T>(),
            adjoint: 1e-5,
            close: 1e-4,
        }
    }
}

/// Runs a test function generic over [`Real`] in f32 and in f64: for each name,
/// `#[test] name::f32` and `#[test] name::f64`.
#[macro_export]
macro_rules! both_precisions {
    ($($name:ident),+ $(,)?) => {
        $(
            mod $name {
                #[test]
                fn f32() {
                    super::$name::<f32>()
                }
                #[test]
                fn f64() {
                    super::$name::<f64>()
                }
            }
        )+
    };
}

/// A seeded pseudo-random field with entries uniform in `[-1, 1)`; the same
/// `(shape, seed)` gives the same field in every run and both precisions (up to
/// rounding).
pub fn random_field<T: Real>(shape: &[usize], seed: u64) -> ArrayD<T> {
    diffphys_tape::test_array(shape, seed)
}

/// Panics with the whole report unless the gradient check passed.
#[track_caller]
pub fn assert_grad_ok(report: &GradCheckReport) {
    assert!(
        report.passed,
        "gradient check failed: max abs err {:.3e}, max rel err {:.3e}, worst entry \
         (input {}, flat index {}) of {} entries",
        report.max_abs_err, report.max_rel_err, report.worst.0, report.worst.1, report.entries
    );
}

/// [`check_gradient`] of `f` at `inputs` with the tolerances of `T`, asserted.
#[track_caller]
pub fn assert_gradient<T: Real, F>(f: F, inputs: &[ArrayD<T>]) -> GradCheckReport
where
    F: for<'t> Fn(&'t Tape<T>, &[Var<'t, T>]) -> diffphys_tape::Result<Var<'t, T>>,
{
    let report = check_gradient(f, inputs, tol::<T>().grad).expect("gradient check ran");
    assert_grad_ok(&report);
    report
}

/// Panics with the report unless the dot-product test passed at the tolerance of `T`.
#[track_caller]
pub fn assert_adjoint_ok<T: Real>(report: &AdjointReport) {
    assert!(
        report.passes(tol::<T>().adjoint),
        "dot-product test failed in {}: <A x, y> = {:e}, <x, Aᵀ y> = {:e}, rel err {:.3e} > {:.0e}",
        T::NAME,
        report.forward_dot,
        report.adjoint_dot,
        report.rel_err,
        tol::<T>().adjoint
    );
}

/// `max |a − b|` over all entries, in f64.
///
/// # Panics
/// If the shapes differ.
#[track_caller]
pub fn max_abs_diff<T: Real>(a: &ArrayD<T>, b: &ArrayD<T>) -> f64 {
    assert_eq!(a.shape(), b.shape(), "max_abs_diff of different shapes");
    a.iter()
        .zip(b)
        .map(|(x, y)| (x.as_f64() - y.as_f64()).abs())
        .fold(0.0, f64::max)
}

/// Asserts `max |actual − expected| ≤ close · max(1, max |expected|)` with the
/// `close` tolerance of `T`; `what` names the quantity in the message.
#[track_caller]
pub fn assert_close<T: Real>(actual: &ArrayD<T>, expected: &ArrayD<T>, what: &str) {
    let scale = expected
        .iter()
        .map(|x| x.as_f64().abs())
        .fold(1.0, f64::max);
    let diff = max_abs_diff(actual, expected);
    let limit = tol::<T>().close * scale;
    assert!(
        diff <= limit,
        "{what} in {}: max abs diff {diff:.3e} > {limit:.3e}",
        T::NAME
    );
}

/// The dense matrix of an operator, built column by column.
pub fn dense_of(a: &dyn LinearOperator<f64>) -> Array2<f64> {
    let n_in: usize = a.input_shape().iter().product();
    let n_out: usize = a.output_shape().iter().product();
    let mut m = Array2::zeros((n_out, n_in));
    for k in 0..n_in {
        let mut e = ArrayD::zeros(IxDyn(a.input_shape()));
        e.as_slice_mut().unwrap()[k] = 1.0;
        let col = a.apply(e.view()).unwrap();
        m.column_mut(k)
            .assign(&ArrayView1::from(col.as_slice().unwrap()));
    }
    m
}

/// The dot-product test `<A x, y> = <x, Aᵀ y>` on pseudo-random vectors, to
/// 1e-14 relative to `‖A‖·‖x‖·‖y‖` (with `‖A‖` bounded by the largest absolute
/// row or column sum, so an operator that is zero up to rounding passes), and
/// the check that the triplets assemble the matrix the operator applies.
pub fn check_operator(a: &dyn LinearOperator<f64>, seed: u64) {
    check_operator_with_scale(a, seed, 0.0);
}

/// [`check_operator`] for a stencil whose coefficients, of magnitude up to
/// `coef`, may cancel to a matrix that is zero up to rounding (a periodic
/// Laplacian on one cell): the tolerance is relative to `max(‖A‖, coef)`.
pub fn check_operator_with_scale(a: &dyn LinearOperator<f64>, seed: u64, coef: f64) {
    let x = test_array::<f64>(a.input_shape(), seed);
    let y = test_array::<f64>(a.output_shape(), seed + 1);
    let rep = check_adjoint(
        |v| a.apply(v).unwrap(),
        |v| a.apply_transpose(v).unwrap(),
        x.view(),
        y.view(),
    )
    .unwrap();
    let dense = dense_of(a);
    let abs = dense.mapv(f64::abs);
    let norm_bound = abs
        .sum_axis(ndarray::Axis(0))
        .iter()
        .chain(abs.sum_axis(ndarray::Axis(1)).iter())
        .fold(coef, |m, &v| m.max(v));
    let norm = |v: &ArrayD<f64>| v.iter().map(|p| p * p).sum::<f64>().sqrt();
    let tol = 1e-14 * norm_bound * norm(&x) * norm(&y);
    assert!(
        (rep.forward_dot - rep.adjoint_dot).abs() <= tol,
        "{}: {rep:?}, tolerance {tol:e}",
        a.name()
    );
    let mut from_triplets = Array2::zeros(dense.raw_dim());
    for (r, c, v) in a.triplets().unwrap() {
        from_triplets[[r, c]] += v;
    }
    let diff = (&from_triplets - &dense)
        .mapv(f64::abs)
        .fold(0.0f64, |m, &v| m.max(v));
    assert!(
        diff <= 1e-12 * norm_bound.max(1.0),
        "{}: triplets off by {diff}",
        a.name()
    );
}
