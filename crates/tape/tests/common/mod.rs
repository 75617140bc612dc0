//! Helpers shared by the tape's integration tests: inputs kept away from kinks and
//! singularities, and the two checks every primitive gets (a finite-difference
//! gradient check in f64, and a run in f32 compared with f64).
//!
//! The operators crate's `tests/common` plays this role for the operators' tests
//! (with the ops-specific tolerances); each crate's tests carry their own.
//!
//! An op is written once as a closure and checked in both precisions:
//!
//! ```ignore
//! check_op!("exp", &[x], |_, v| v[0].exp());
//! ```

// Each test file uses a different part of this module.
#![allow(dead_code, unused_macros)]

use diffphys_tape::{
    check_gradient, test_array, ArrayD, GradCheckOptions, Real, Result, Tape, Var,
};

/// How far an f32 evaluation may be from the f64 one, relative to the largest
/// magnitude of the f64 result. f32 rounds at 6e-8; the ops checked here amplify
/// that by at most a few hundred (sums of a few dozen terms, mild conditioning).
pub const F32_VS_F64: f64 = 1e-3;

/// The seed of the weight that contracts a non-scalar output to a scalar.
const WEIGHT_SEED: u64 = 0x5EED;

/// Entries uniform in `±[0.25, 1.25)`: away from the kinks of `abs`, `relu` and
/// from the pole of `1/x`, by far more than a finite-difference step.
pub fn away_from_zero(shape: &[usize], seed: u64) -> ArrayD<f64> {
    test_array::<f64>(shape, seed).mapv(|x| x + 0.25 * x.signum())
}

/// Entries uniform in `[0.25, 1.25)`, for `ln` and `sqrt`.
pub fn positive(shape: &[usize], seed: u64) -> ArrayD<f64> {
    test_array::<f64>(shape, seed).mapv(|x| 0.25 + x.abs())
}

/// Entries on the odd tenths `±0.1, ±0.3, …` (`odd = true`) or the even tenths
/// `0, ±0.2, …`: an odd and an even array never tie anywhere, by at least 0.1,
/// however they broadcast against each other (for `minimum`, `maximum`).
pub fn tenths(shape: &[usize], seed: u64, odd: bool) -> ArrayD<f64> {
    let offset = if odd { 0.1 } else { 0.0 };
    test_array::<f64>(shape, seed).mapv(|x| (x * 5.0).round() * 0.2 + offset)
}

/// The value of `f` at `inputs` and the gradients of `<w, f>` for every input
/// (with `w` a fixed weight exactly representable in f32, or 1 for a scalar
/// output), all in f64.
pub fn value_and_grads<T: Real, F>(f: &F, inputs: &[ArrayD<T>]) -> (ArrayD<f64>, Vec<ArrayD<f64>>)
where
    F: for<'t> Fn(&'t Tape<T>, &[Var<'t, T>]) -> Result<Var<'t, T>>,
{
    let tape = Tape::new();
    let vars: Vec<_> = inputs.iter().map(|x| tape.var(x.clone())).collect();
    let out = f(&tape, &vars).expect("forward");
    let shape = out.shape();
    let grads = if shape.iter().product::<usize>() == 1 {
        tape.backward(out, &vars)
    } else {
        let weight = test_array::<f32>(&shape, WEIGHT_SEED).mapv(|w| T::from_f64(f64::from(w)));
        tape.backward_with_seed(out, weight, &vars)
    }
    .expect("backward");
    let to_f64 = |a: &ArrayD<T>| a.mapv(|x| x.as_f64());
    let grads = vars
        .iter()
        .map(|v| to_f64(grads.get(*v).expect("requested gradient")))
        .collect();
    let value = to_f64(&out.value());
    (value, grads)
}

/// Asserts that `f32_result` is finite and within [`F32_VS_F64`] of `f64_result`,
/// relative to the largest magnitude of the latter.
#[track_caller]
pub fn assert_f32_agrees(what: &str, f32_result: &ArrayD<f64>, f64_result: &ArrayD<f64>) {
    assert_eq!(f32_result.shape(), f64_result.shape(), "{what}: shapes");
    assert!(
        f32_result.iter().all(|x| x.is_finite()),
        "{what}: non-finite in f32: {f32_result}"
    );
    let scale = f64_result.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    let diff = f32_result
        .iter()
        .zip(f64_result)
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(
        diff <= F32_VS_F64 * scale,
        "{what}: f32 differs from f64 by {diff:.3e} (scale {scale:.3e})"
    );
}

/// The two checks of one op: its gradient against central finite differences in
/// f64, and its value and gradients in f32 against those in f64. `f64_fn` and
/// `f32_fn` are the same closure (see [`check_op!`]).
#[track_caller]
pub fn check_op<F, G>(name: &str, inputs: &[ArrayD<f64>], f64_fn: F, f32_fn: G)
where
    F: for<'t> Fn(&'t Tape<f64>, &[Var<'t, f64>]) -> Result<Var<'t, f64>>,
    G: for<'t> Fn(&'t Tape<f32>, &[Var<'t, f32>]) -> Result<Var<'t, f32>>,
{
    let report = check_gradient(&f64_fn, inputs, GradCheckOptions::for_type::<f64>())
        .unwrap_or_else(|e| panic!("{name}: gradient check failed to run: {e}"));
    assert!(
        report.passed,
        "{name}: f64 gradient check failed: {report:?}"
    );
    assert_eq!(
        report.entries,
        inputs.iter().map(ArrayD::len).sum::<usize>(),
        "{name}: every input entry checked"
    );

    let (y64, g64) = value_and_grads(&f64_fn, inputs);
    let inputs32: Vec<ArrayD<f32>> = inputs.iter().map(|a| a.mapv(|x| x as f32)).collect();
    let (y32, g32) = value_and_grads(&f32_fn, &inputs32);
    assert_f32_agrees(&format!("{name} value"), &y32, &y64);
    for (k, (a, b)) in g32.iter().zip(&g64).enumerate() {
        assert_f32_agrees(&format!("{name} gradient of input {k}"), a, b);
    }
}

/// [`check_op`] with one closure written once for both precisions.
macro_rules! check_op {
    ($name:expr, $inputs:expr, $f:expr) => {
        $crate::common::check_op($name, $inputs, $f, $f)
    };
}
