//! candle's gradient through the wrapped operators equals the gradient our tape
//! computes for the same loss, in f64 and f32.

use std::sync::Arc;

use candle_core::{DType, Device, Tensor, Var as CandleVar, WithDType};
use diffphys_candle::{CandlePoisson, CandleUpwind1};
use diffphys_ops::advection::{AdvectionParams, Upwind1};
use diffphys_ops::cg::CgParams;
use diffphys_ops::poisson::PoissonSolve;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid1, Grid2};
use diffphys_tape::{test_array, ArrayD, Real, Tape};

fn tensor<T: Real + WithDType>(a: &ArrayD<T>) -> Tensor {
    Tensor::from_vec(
        a.iter().copied().collect::<Vec<T>>(),
        a.shape(),
        &Device::Cpu,
    )
    .unwrap()
}

fn array<T: Real + WithDType>(t: &Tensor) -> ArrayD<T> {
    let v = t.flatten_all().unwrap().to_vec1::<T>().unwrap();
    ArrayD::from_shape_vec(t.dims(), v).unwrap()
}

fn max_abs_diff<T: Real>(a: &ArrayD<T>, b: &ArrayD<T>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x.as_f64() - y.as_f64()).abs())
        .fold(0.0, f64::max)
}

/// `L = Σ w ⊙ x²` with `x = A⁻¹ b`, `A = −∇²` on 12×10 cells with zero walls:
/// the gradient with respect to `b` from candle and from the tape.
fn poisson_gradients<T: Real + WithDType>(rtol: f64) -> (ArrayD<T>, ArrayD<T>) {
    let grid = Grid2::new(12, 10, 1.0, 1.0, Boundary::ZeroDirichlet).unwrap();
    let op = Arc::new(Laplacian2::negative(grid));
    let params = CgParams {
        rel_tol: rtol,
        ..CgParams::default()
    };
    let b = test_array::<T>(&[12, 10], 1);
    let w = test_array::<T>(&[12, 10], 2);

    let bv = CandleVar::from_tensor(&tensor(&b)).unwrap();
    let x = CandlePoisson::new(Arc::clone(&op), params.clone())
        .apply(bv.as_tensor())
        .unwrap();
    let loss = x
        .sqr()
        .unwrap()
        .mul(&tensor(&w))
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    let candle = array::<T>(grads.get(bv.as_tensor()).unwrap());

    let tape = Tape::<T>::new();
    let bt = tape.var(b);
    let x = tape.apply(PoissonSolve::new(op, params), &[bt]).unwrap();
    let loss = x
        .mul(x)
        .unwrap()
        .mul(tape.constant(w))
        .unwrap()
        .sum()
        .unwrap();
    let ours = tape.backward(loss, &[bt]).unwrap().get(bt).unwrap().clone();
    (candle, ours)
}

/// `L = Σ w ⊙ d'` with `d'` one upwind step of `d` by `u` (both signs of `u`):
/// the gradients with respect to `d` and `u` from candle and from the tape.
fn upwind_gradients<T: Real + WithDType>() -> [(ArrayD<T>, ArrayD<T>); 2] {
    let grid = Grid1::new(16, 0.1, 0.0, Boundary::Periodic).unwrap();
    let params = AdvectionParams::new(0.05);
    let d = test_array::<T>(&[16], 3);
    let u = test_array::<T>(&[16], 4);
    let w = test_array::<T>(&[16], 5);

    let (dv, uv) = (
        CandleVar::from_tensor(&tensor(&d)).unwrap(),
        CandleVar::from_tensor(&tensor(&u)).unwrap(),
    );
    let out = CandleUpwind1::new(grid, params)
        .apply(dv.as_tensor(), uv.as_tensor())
        .unwrap();
    // Squared, so that the gradient in u depends on d' and not only on w.
    let loss = out
        .sqr()
        .unwrap()
        .mul(&tensor(&w))
        .unwrap()
        .sum_all()
        .unwrap();
    let grads = loss.backward().unwrap();
    let candle = [dv.as_tensor(), uv.as_tensor()].map(|t| array::<T>(grads.get(t).unwrap()));

    let tape = Tape::<T>::new();
    let (dt, ut) = (tape.var(d), tape.var(u));
    let out = tape.apply(Upwind1::new(grid, params), &[dt, ut]).unwrap();
    let loss = out
        .mul(out)
        .unwrap()
        .mul(tape.constant(w))
        .unwrap()
        .sum()
        .unwrap();
    let g = tape.backward(loss, &[dt, ut]).unwrap();
    let ours = [dt, ut].map(|v| g.get(v).unwrap().clone());
    let [cd, cu] = candle;
    let [od, ou] = ours;
    [(cd, od), (cu, ou)]
}

#[test]
fn poisson_gradients_agree_with_the_tape() {
    let (candle, ours) = poisson_gradients::<f64>(1e-10);
    let scale = ours.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(
        scale > 1e-3,
        "a gradient that is not trivially zero: {scale}"
    );
    let diff = max_abs_diff(&candle, &ours);
    assert!(diff <= 1e-10, "f64: {diff:e}");
    let (candle, ours) = poisson_gradients::<f32>(1e-5);
    let diff = max_abs_diff(&candle, &ours);
    assert!(diff <= 1e-5 * scale, "f32: {diff:e}");
}

#[test]
fn upwind_gradients_agree_with_the_tape() {
    for (candle, ours) in upwind_gradients::<f64>() {
        let diff = max_abs_diff(&candle, &ours);
        assert!(diff <= 1e-10, "f64: {diff:e}");
    }
    for (candle, ours) in upwind_gradients::<f32>() {
        let diff = max_abs_diff(&candle, &ours);
        assert!(diff <= 1e-5, "f32: {diff:e}");
    }
}

#[test]
fn bad_input_is_a_candle_error_not_a_panic() {
    let grid = Grid2::new(4, 4, 1.0, 1.0, Boundary::ZeroDirichlet).unwrap();
    let solve = CandlePoisson::new(Arc::new(Laplacian2::negative(grid)), CgParams::default());
    let wrong_shape = Tensor::zeros((3, 4), DType::F64, &Device::Cpu).unwrap();
    let err = solve.apply(&wrong_shape).unwrap_err();
    assert!(err.to_string().contains("[3, 4]"), "{err}");
    let ints = Tensor::zeros((4, 4), DType::U32, &Device::Cpu).unwrap();
    assert!(solve.apply(&ints).is_err());
    // A CFL violation: |u| dt/dx = 10.
    let step = CandleUpwind1::new(
        Grid1::new(8, 0.1, 0.0, Boundary::Periodic).unwrap(),
        AdvectionParams::new(1.0),
    );
    let d = Tensor::zeros(8, DType::F64, &Device::Cpu).unwrap();
    let err = step.apply(&d, &d.ones_like().unwrap()).unwrap_err();
    assert!(err.to_string().to_lowercase().contains("cfl"), "{err}");
    let mixed = step.apply(&d, &Tensor::zeros(8, DType::F32, &Device::Cpu).unwrap());
    assert!(mixed.is_err());
}
