//! Any linear operator as a tape op ([`LinearOp`]): gradients through stencils
//! and their transposes against finite differences, boxed and shared operators,
//! and the errors of a wrong shape.

use std::sync::Arc;

use diffphys_ops::stencil::{Divergence2, Gradient1, Gradient2, Laplacian2};
use diffphys_ops::tape_ops::LinearOp;
use diffphys_ops::{Boundary, Grid1, Grid2, LinearOperator};
use diffphys_tape::{check_gradient, test_array, ArrayD, GradCheckOptions, Tape, TapeError};

#[test]
fn gradient_through_linear_ops_matches_finite_differences() {
    let grid = Grid2::new(5, 4, 0.3, 0.2, Boundary::Closed)
        .unwrap()
        .with_boundaries(Boundary::ZeroDirichlet, Boundary::Periodic);
    let lap = Arc::new(Laplacian2::new(grid));
    let grad = Arc::new(Gradient2::new(grid));
    let div = Divergence2::new(grid);
    let x = test_array::<f64>(&[5, 4], 11);
    // f(x) = Σ x ⊙ ∇²x + Σ (D G x)², nonlinear so every entry is checked;
    // ∂f/∂x = (A + Aᵀ) x + 2 Gᵀ Dᵀ (D G x).
    let report = check_gradient(
        |t, v| {
            let ax = t.apply(LinearOp::new(Arc::clone(&lap)), &[v[0]])?;
            let gx = t.apply(LinearOp::new(Arc::clone(&grad)), &[v[0]])?;
            let dgx = t.apply(LinearOp::new(div.clone()), &[gx])?;
            v[0].mul(ax)?.sum()?.add(dgx.mul(dgx)?.sum()?)
        },
        &[x],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
}

#[test]
fn transpose_op_gradient_and_boxed_operators() {
    let g = Grid1::new(6, 0.5, 0.0, Boundary::ZeroDirichlet).unwrap();
    let boxed: Box<dyn LinearOperator<f64> + Send + Sync> = Box::new(Gradient1::new(g));
    let shared = Arc::new(boxed);
    let y = test_array::<f64>(&[6], 3);
    let report = check_gradient(
        |t, v| {
            let gty = t.apply(LinearOp::transposed(Arc::clone(&shared)), &[v[0]])?;
            gty.mul(gty)?.sum()
        },
        &[y],
        GradCheckOptions::for_type::<f64>(),
    )
    .unwrap();
    assert!(report.passed, "{report:?}");
}

#[test]
fn constant_input_records_nothing_and_wrong_shape_is_an_error() {
    let grid = Grid2::new(3, 3, 1.0, 1.0, Boundary::Periodic).unwrap();
    let tape = Tape::<f64>::new();
    let c = tape.constant(ArrayD::zeros(vec![3, 3]));
    tape.apply(LinearOp::new(Laplacian2::new(grid)), &[c])
        .unwrap();
    assert_eq!(tape.stats().nodes, 0);
    let bad = tape.var(ArrayD::zeros(vec![3, 4]));
    let err = tape
        .apply(LinearOp::new(Laplacian2::new(grid)), &[bad])
        .unwrap_err();
    assert!(matches!(err, TapeError::Op { .. }), "{err:?}");
}
