//! The implicit Poisson solve: its gradient against finite differences and
//! against the exact (sparse Cholesky) gradient, its adjoint, warm starts, and
//! how solver failures surface on the tape.

mod common;

use std::sync::Arc;

use common::*;
use diffphys_ops::cg::{CgError, CgParams, NullSpace};
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::poisson::{poisson_solve, poisson_solve_vjp, PoissonSolve, SolveLog, WarmStart};
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::{Boundary, Grid2};
use diffphys_tape::Op;
use ndarray::ArrayD;

/// The two kinds of systems: definite (Dirichlet walls) and singular
/// (closed walls, constants in the kernel).
fn systems(nx: usize, ny: usize) -> Vec<(Laplacian2, NullSpace)> {
    [
        (Boundary::ZeroDirichlet, NullSpace::None),
        (Boundary::Closed, NullSpace::Constant),
    ]
    .into_iter()
    .map(|(b, ns)| {
        let grid = Grid2::new(nx, ny, 0.5, 0.25, b).unwrap();
        (Laplacian2::negative(grid), ns)
    })
    .collect()
}

fn rel_err<T: Real>(g: &ArrayD<T>, exact: &ArrayD<f64>) -> f64 {
    let num: f64 = g
        .iter()
        .zip(exact)
        .map(|(a, b)| (a.as_f64() - b).powi(2))
        .sum();
    (num / exact.iter().map(|b| b * b).sum::<f64>()).sqrt()
}

#[test]
fn gradient_matches_finite_differences() {
    for (a, ns) in systems(6, 5) {
        let solve = PoissonSolve::new(
            Arc::new(a),
            CgParams::default().with_rel_tol(1e-13).with_null_space(ns),
        );
        let b = random_field::<f64>(&[6, 5], 21);
        // L = Σ w ⊙ p² (w the checker's weight): nonlinear in p, so every entry
        // of grad_b = A⁻¹ (2 w ⊙ p) is exercised.
        assert_gradient(
            |t, v| {
                let p = t.apply(solve.clone(), &[v[0]])?;
                p.mul(p)
            },
            &[b],
        );
    }
}

#[test]
fn gradient_matches_the_exact_gradient() {
    for (a, ns) in systems(24, 20) {
        let exact = SparseCholesky::new(&a, ns.clone()).unwrap();
        let b = random_field::<f64>(&[24, 20], 3);
        let target = random_field::<f64>(&[24, 20], 4);
        // L = ½‖p − t‖²: grad_p = p − t, grad_b = A⁻¹ (p − t) (mean removed).
        let p_exact = exact.solve(b.view()).unwrap();
        let g_exact = exact.solve((&p_exact - &target).view()).unwrap();

        let params = CgParams::default().with_rel_tol(1e-10).with_null_space(ns);
        let solve = PoissonSolve::new(Arc::new(a), params);
        let log = solve.log();
        let tape = Tape::<f64>::new();
        let bv = tape.var(b.clone());
        let p = tape.apply(solve, &[bv]).unwrap();
        let d = p.sub(tape.constant(target.clone())).unwrap();
        let loss = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
        let grads = tape.backward(loss, &[bv]).unwrap();
        let g = grads.get(bv).unwrap();
        assert!(rel_err(&p.to_array(), &p_exact) < 1e-8);
        let err = rel_err(g, &g_exact);
        assert!(err < 1e-8, "{err:.3e}");
        assert_eq!((log.forward_solves(), log.adjoint_solves()), (1, 1));
        assert!(log.last_adjoint().unwrap().relative_residual <= 1e-10);
    }
}

/// With a multigrid V-cycle as the preconditioner of both solves, forward and
/// adjoint converge in a few iterations and the gradient is the exact one.
#[test]
fn multigrid_preconditioned_gradient_matches_the_exact_gradient() {
    for (b_kind, ns) in [
        (Boundary::ZeroDirichlet, NullSpace::None),
        (Boundary::Closed, NullSpace::Constant),
        (Boundary::Periodic, NullSpace::Constant),
    ] {
        let grid = Grid2::new(32, 16, 0.5, 0.5, b_kind).unwrap();
        let a = Laplacian2::negative(grid);
        let exact = SparseCholesky::new(&a, ns.clone()).unwrap();
        let b = random_field::<f64>(&[32, 16], 5);
        let target = random_field::<f64>(&[32, 16], 6);
        let p_exact = exact.solve(b.view()).unwrap();
        let g_exact = exact.solve((&p_exact - &target).view()).unwrap();

        let mg = Arc::new(Multigrid::new(&grid, 2).unwrap());
        let params = CgParams::default()
            .with_rel_tol(1e-10)
            .with_null_space(ns)
            .with_preconditioner(mg);
        let solve = PoissonSolve::new(Arc::new(a), params);
        let log = solve.log();
        let tape = Tape::<f64>::new();
        let bv = tape.var(b.clone());
        let p = tape.apply(solve, &[bv]).unwrap();
        let d = p.sub(tape.constant(target.clone())).unwrap();
        let loss = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
        let grads = tape.backward(loss, &[bv]).unwrap();
        let err = rel_err(grads.get(bv).unwrap(), &g_exact);
        assert!(err < 1e-8, "{b_kind:?}: {err:.3e}");
        let (fwd, adj) = (log.last_forward().unwrap(), log.last_adjoint().unwrap());
        assert!(
            fwd.iterations <= 12 && adj.iterations <= 12,
            "{b_kind:?}: {} + {} iterations",
            fwd.iterations,
            adj.iterations
        );
    }
}

/// The warm-started op (both solves start from the previous step's solutions)
/// over a sequence of right-hand sides, as in an optimisation loop: each step's
/// `∂L/∂b` against the exact gradient of that step.
#[test]
fn warm_started_gradient_matches_the_exact_gradient() {
    for (a, ns) in systems(24, 20) {
        let exact = SparseCholesky::new(&a, ns.clone()).unwrap();
        let target = random_field::<f64>(&[24, 20], 4);
        let params = CgParams::default().with_rel_tol(1e-10).with_null_space(ns);
        let log = SolveLog::new();
        let solve = PoissonSolve::new(Arc::new(a), params)
            .with_warm_start(WarmStart::both())
            .with_log(log.clone());
        let mut cold_iterations = 0;
        for step in 0..3 {
            // b drifts a little from step to step.
            let b = random_field::<f64>(&[24, 20], 3)
                + random_field::<f64>(&[24, 20], 10 + step) * 0.05;
            let p_exact = exact.solve(b.view()).unwrap();
            let g_exact = exact.solve((&p_exact - &target).view()).unwrap();
            let tape = Tape::<f64>::new();
            let bv = tape.var(b);
            let p = tape.apply(solve.clone(), &[bv]).unwrap();
            let d = p.sub(tape.constant(target.clone())).unwrap();
            let loss = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
            let grads = tape.backward(loss, &[bv]).unwrap();
            let err = rel_err(grads.get(bv).unwrap(), &g_exact);
            assert!(err < 1e-8, "step {step}: {err:.3e}");
            let iterations = log.last_forward().unwrap().iterations;
            if step == 0 {
                cold_iterations = iterations;
            } else {
                // The warm start is in use: fewer iterations than from zero.
                assert!(
                    iterations < cold_iterations,
                    "step {step}: {iterations} vs {cold_iterations}"
                );
            }
        }
        assert_eq!((log.forward_solves(), log.adjoint_solves()), (3, 3));
    }
}

#[test]
fn f32_gradient_on_64x64_is_within_1e_4_of_exact() {
    // The stability study's accuracy floor for the implicit f32 gradient.
    for (a, ns) in systems(64, 64) {
        let exact = SparseCholesky::new(&a, ns.clone()).unwrap();
        let b = random_field::<f64>(&[64, 64], 7);
        let target = random_field::<f64>(&[64, 64], 8);
        let p_exact = exact.solve(b.view()).unwrap();
        let g_exact = exact.solve((&p_exact - &target).view()).unwrap();

        // 1e-5 lies near f32's rounding floor here: a solve may stop at the
        // floor (flagged), not at the cap.
        let params = CgParams::default()
            .with_rel_tol(1e-5)
            .with_null_space(ns)
            .with_require_convergence(false);
        let solve = PoissonSolve::<f32, _>::new(Arc::new(a), params);
        let log = solve.log();
        let tape = Tape::<f32>::new();
        let bv = tape.var(b.mapv(|v| v as f32));
        let p = tape.apply(solve, &[bv]).unwrap();
        let d = p.sub(tape.constant(target.mapv(|v| v as f32))).unwrap();
        let loss = d.mul(d).unwrap().sum().unwrap().mul_scalar(0.5).unwrap();
        let grads = tape.backward(loss, &[bv]).unwrap();
        for info in [log.last_forward(), log.last_adjoint()] {
            assert!(!info.as_ref().unwrap().reached_cap(), "{info:?}");
        }
        let err = rel_err(grads.get(bv).unwrap(), &g_exact);
        assert!(err < 1e-4, "{err:.3e}");
    }
}

/// The solve is a linear map `S`; its VJP must be `Sᵀ = S`.
fn solve_passes_the_dot_product_test<T: Real>() {
    for (a, ns) in systems(9, 7) {
        let rtol = if T::EPS.as_f64() < 1e-10 { 1e-13 } else { 1e-6 };
        let params = CgParams::default().with_rel_tol(rtol).with_null_space(ns);
        let x = random_field::<T>(&[9, 7], 1);
        let y = random_field::<T>(&[9, 7], 2);
        let report = check_adjoint(
            |b| poisson_solve(&a, b, &params).unwrap().0,
            |g| poisson_solve_vjp(&a, g, &params, None).unwrap().0,
            x.view(),
            y.view(),
        )
        .unwrap();
        // Two independent solves at tolerance rtol: the products agree to
        // about κ·rtol, not to rounding.
        assert!(report.passes(1e3 * rtol), "{report:?}");
    }
}

both_precisions!(solve_passes_the_dot_product_test);

#[test]
fn adjoint_has_its_own_tolerance_and_warm_start() {
    let (a, _) = systems(32, 32).remove(0);
    let a = Arc::new(a);
    let b = random_field::<f64>(&[32, 32], 5);
    let log = SolveLog::new();
    let solve = PoissonSolve::new(Arc::clone(&a), CgParams::default().with_rel_tol(1e-10))
        .with_adjoint_params(CgParams::default().with_rel_tol(1e-4))
        .with_warm_start(WarmStart {
            forward: false,
            adjoint: true,
        })
        .with_log(log.clone());
    assert_eq!(solve.saved_bytes(), 0);
    let step = |solve: PoissonSolve<f64, Laplacian2>| {
        let tape = Tape::<f64>::new();
        let bv = tape.var(b.clone());
        let p = tape.apply(solve, &[bv]).unwrap();
        let loss = p.sum().unwrap();
        tape.backward(loss, &[bv]).unwrap().get(bv).unwrap().clone()
    };
    let g1 = step(solve.clone());
    let (fwd, adj) = (log.last_forward().unwrap(), log.last_adjoint().unwrap());
    // A looser adjoint tolerance takes fewer iterations.
    assert!(adj.iterations < fwd.iterations, "{adj:?} vs {fwd:?}");
    assert!(adj.relative_residual <= 1e-4 && fwd.relative_residual <= 1e-10);
    // The same step again: the adjoint starts from its previous solution, which
    // already solves the same system.
    let g2 = step(solve);
    assert_eq!(log.last_adjoint().unwrap().iterations, 0);
    assert_eq!(g1, g2);
    assert_eq!((log.forward_solves(), log.adjoint_solves()), (2, 2));
    assert_eq!(log.warm_start_bytes(), 32 * 32 * 8);
}

#[test]
fn solver_failures_surface_as_tape_errors_naming_the_op() {
    let (a, _) = systems(32, 32).remove(1); // closed walls, but no null space declared
    let solve = PoissonSolve::new(
        Arc::new(a),
        CgParams::default().with_rel_tol(1e-10).with_max_iters(3),
    );
    let tape = Tape::<f64>::new();
    let b = tape.var(random_field(&[32, 32], 6));
    let err = tape.apply(solve.clone(), &[b]).unwrap_err();
    let TapeError::Op { op, cause, .. } = &err else {
        panic!("expected a tape op error, got {err:?}");
    };
    assert_eq!(op, "poisson_solve");
    assert!(matches!(
        cause.downcast_ref::<CgError>(),
        Some(CgError::NoConvergence { iterations: 3, .. })
    ));
    assert!(err
        .to_string()
        .starts_with("poisson_solve failed: conjugate gradient did not converge"));

    // NaN in b: a NonFinite CgError, not a NaN pressure.
    let mut bad = random_field::<f64>(&[32, 32], 6);
    bad[[3, 4]] = f64::NAN;
    let err = tape.apply(solve.clone(), &[tape.var(bad)]).unwrap_err();
    let TapeError::Op { cause, .. } = &err else {
        panic!("{err:?}");
    };
    assert!(matches!(
        cause.downcast_ref::<CgError>(),
        Some(CgError::NonFinite { iteration: 0, .. })
    ));

    // A wrong shape.
    let err = tape
        .apply(solve, &[tape.var(random_field(&[31, 32], 6))])
        .unwrap_err();
    assert!(matches!(err, TapeError::ShapeMismatch { .. }), "{err:?}");
}
