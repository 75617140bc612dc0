//! Every failure mode of the stability study, provoked on a small grid, with its
//! outcome asserted: where a method fails it fails with a typed error naming the
//! op (and the iteration or step); where it is robust it stays finite.

use diffphys_compare::harness::{measure, relative_error};
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::implicit::{
    implicit_initial_guess_gradient, ImplicitSeparateAdjoint, ImplicitSolve,
};
use diffphys_compare::methods::naive::NaiveUnrolled;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::problem::{OperatorKind, Problem, ProblemSpec};
use diffphys_compare::progress::NoProgress;
use diffphys_compare::stability::{
    convergence_iterations, f32_floor, floor_study, null_space_fraction, run_stability,
    stability_key_figures, unroll_gradient, write_stability_charts, StabilityConfig,
    F32_FLOOR_LIMIT,
};
use diffphys_compare::CompareError;
use diffphys_tape::{Pass, TapeError};
use ndarray::Array2;

fn exact(spec: ProblemSpec) -> Array2<f64> {
    let p = Problem::<f64>::new(spec).unwrap();
    ExactCholesky.run(&p, Stop::Iterations(0)).unwrap().gradient
}

fn tol(rtol: f64) -> Stop {
    Stop::Tolerance {
        rtol,
        max_iters: 20_000,
    }
}

#[test]
fn naive_past_convergence_fails_in_f32_while_implicit_stays_accurate() {
    let spec = ProblemSpec::laplacian(16);
    let g = exact(spec);
    let problem = Problem::<f32>::new(spec).unwrap();
    let k = convergence_iterations(&Problem::<f64>::new(spec).unwrap()).unwrap();
    let stop = Stop::Iterations(10 * k);

    let err = NaiveUnrolled::default().run(&problem, stop).unwrap_err();
    match &err {
        CompareError::NaiveIteration {
            iteration,
            source: TapeError::NonFinite { op, pass, .. },
        } => {
            // β = ‖r_{k+1}‖²/‖r_k‖², α = ‖r_k‖²/<p, A p>: vanishing denominators.
            assert_eq!(op, "div");
            assert_eq!(*pass, Pass::Backward);
            assert!(
                *iteration > k && *iteration < 10 * k,
                "iteration {iteration}"
            );
        }
        other => panic!("expected a non-finite naive iteration, got {other:?}"),
    }
    assert!(err.is_non_finite());
    assert!(err.to_string().contains("iteration") && err.to_string().contains("div"));

    // Same run, same precision: the implicit gradient stays finite and accurate.
    let (row, _) = measure(&ImplicitSolve, &problem, Some(stop), None, Some(&g));
    assert!(row.finite && row.error.is_none(), "{row:?}");
    assert!(row.grad_rel_err.unwrap() < 1e-5, "{row:?}");

    // Just past convergence the naive f32 gradient is still finite but far worse.
    let (naive, _) = measure(
        &NaiveUnrolled::default(),
        &problem,
        Some(Stop::Iterations(2 * k)),
        None,
        Some(&g),
    );
    let (implicit, _) = measure(
        &ImplicitSolve,
        &problem,
        Some(Stop::Iterations(2 * k)),
        None,
        Some(&g),
    );
    let (n_err, i_err) = (naive.grad_rel_err.unwrap(), implicit.grad_rel_err.unwrap());
    assert!(
        n_err > 100.0 * i_err,
        "naive {n_err:e} vs implicit {i_err:e}"
    );
}

#[test]
fn implicit_f32_floor_holds_at_every_cap_on_a_small_grid() {
    // The floor's range of caps, from convergence to 1000, on 16²: far past
    // convergence, where an f32 CG that kept iterating broke down.
    let n = 16;
    let g = exact(ProblemSpec::laplacian(n));
    let from =
        convergence_iterations(&Problem::<f32>::new(ProblemSpec::laplacian(n)).unwrap()).unwrap();
    let rows = floor_study(n, from, 1000, 1, Some(&g), &NoProgress).unwrap();
    assert_eq!(rows.len(), 1000 - from + 1);
    let floor = f32_floor(&rows, n, from, 1000);
    assert_eq!(floor.holds(), Some(true), "{floor:?}");
    assert!(rows.iter().all(|r| r.row.finite && r.row.error.is_none()));
    assert!(floor.measured.unwrap() <= F32_FLOOR_LIMIT);
}

#[test]
fn f32_solver_stops_at_its_rounding_floor_instead_of_breaking_down() {
    // Fixed counts far past convergence: the solver stops once the recurrence
    // has fallen far below what f32 resolves, instead of iterating until the
    // curvature underflows (which reads as "not positive definite").
    let problem = Problem::<f32>::new(ProblemSpec::laplacian(32)).unwrap();
    let out = ImplicitSolve.run(&problem, Stop::Iterations(2000)).unwrap();
    let (fwd, adj) = (out.iterations.unwrap(), out.adjoint_iterations.unwrap());
    assert!(fwd < 2000 && adj < 2000, "{fwd}+{adj}");
    assert!(out.gradient.iter().all(|v| v.is_finite()));
    assert!(out.forward_residual.unwrap() < 1e-4);
}

#[test]
fn unconverged_implicit_error_tracks_the_forward_residual() {
    let spec = ProblemSpec::laplacian(16);
    let g = exact(spec);
    let problem = Problem::<f64>::new(spec).unwrap();
    let tight = ImplicitSeparateAdjoint {
        adjoint: tol(1e-12),
    };
    let mut last = f64::INFINITY;
    for rtol in [1e-2, 1e-4, 1e-6, 1e-8] {
        let (row, _) = measure(&tight, &problem, Some(tol(rtol)), None, Some(&g));
        let (err, res) = (
            row.grad_rel_err.unwrap(),
            row.reached_relative_residual.unwrap(),
        );
        assert!(res <= rtol * 1.01, "residual {res:e} above rtol {rtol:e}");
        // The error is of the order of the residual: never far above it.
        assert!(
            err <= 10.0 * res && err > 1e-4 * res,
            "rtol {rtol:e}: {err:e} vs {res:e}"
        );
        assert!(err < last);
        last = err;
    }
    // The naive gradient is only as good as its iteration count.
    let k = convergence_iterations(&problem).unwrap();
    let err_at = |iters: usize| {
        let (row, _) = measure(
            &NaiveUnrolled::default(),
            &problem,
            Some(Stop::Iterations(iters)),
            None,
            Some(&g),
        );
        row.grad_rel_err.unwrap()
    };
    assert!(err_at(k / 4) > 1e-3);
    assert!(err_at(k) < 1e-8);
}

#[test]
fn initial_guess_gradient_is_zero_for_implicit_and_not_for_naive() {
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(12)).unwrap();
    let x0 = diffphys_tape::test_array::<f64>(&[12, 12], 5)
        .into_dimensionality()
        .unwrap()
        * 0.05;
    for stop in [Stop::Iterations(5), Stop::Iterations(20), tol(1e-10)] {
        let (_, gb, g0) = implicit_initial_guess_gradient(&problem, stop, &x0).unwrap();
        assert!(
            g0.iter().all(|&v| v == 0.0),
            "implicit ∂L/∂x0 must be exactly 0"
        );
        assert!(gb.iter().any(|&v| v != 0.0));
    }
    // Solved to a tolerance from the initial guess, ∂L/∂b is the exact gradient.
    let exact = ExactCholesky.run(&problem, Stop::Iterations(0)).unwrap();
    let (_, gb, _) = implicit_initial_guess_gradient(&problem, tol(1e-10), &x0).unwrap();
    let err = relative_error(&gb, &exact.gradient).unwrap();
    assert!(err < 1e-8, "warm-started implicit ∂L/∂b vs exact: {err:e}");
    // Naive: the derivative of the truncated iteration, non-zero, and it agrees
    // with a central difference of the naive loss in x0.
    let stop = Stop::Iterations(5);
    let naive = NaiveUnrolled::default();
    let (_, g0) = naive.run_from(&problem, stop, Some(&x0)).unwrap();
    let g0 = g0.unwrap();
    let norm: f64 = g0.iter().map(|v| v * v).sum::<f64>().sqrt();
    assert!(norm > 1e-3, "naive ‖∂L/∂x0‖ = {norm:e}");
    let d = diffphys_tape::test_array::<f64>(&[12, 12], 9)
        .into_dimensionality::<ndarray::Ix2>()
        .unwrap();
    let h = 1e-5;
    let loss = |x: &Array2<f64>| naive.run_from(&problem, stop, Some(x)).unwrap().0.loss;
    let fd = (loss(&(&x0 + &(&d * h))) - loss(&(&x0 - &(&d * h)))) / (2.0 * h);
    let an = (&g0 * &d).sum();
    assert!(
        (fd - an).abs() <= 1e-6 * an.abs().max(1e-12),
        "fd {fd:e} vs {an:e}"
    );
}

#[test]
fn unroll_gradient_explodes_above_cfl_one_and_stays_bounded_below() {
    // Below 1: the upwind step is a contraction in the adjoint too.
    let (_, g1, _) = unroll_gradient::<f64>(32, 0.5, 1).unwrap();
    for steps in [4, 16, 64, 256, 1024] {
        let (loss, gd, gu) = unroll_gradient::<f64>(32, 0.5, steps).unwrap();
        assert!(loss.is_finite() && gu.is_finite());
        assert!(gd <= 1.5 * g1, "CFL 0.5, {steps} steps: {gd:e} vs {g1:e}");
    }
    // Above 1: the gradient norm grows geometrically with the steps…
    let (_, a, _) = unroll_gradient::<f64>(32, 1.5, 8).unwrap();
    let (_, b, _) = unroll_gradient::<f64>(32, 1.5, 64).unwrap();
    assert!(b > 1e10 * a, "CFL 1.5: {a:e} at 8 steps, {b:e} at 64");
    // …until it leaves f32's range: a typed error naming the op and the step.
    let err = unroll_gradient::<f32>(32, 1.5, 256).unwrap_err();
    match &err {
        CompareError::UnrollStep { step, .. } => assert!(*step < 256),
        other => panic!("expected an unroll step error, got {other:?}"),
    }
    assert!(err.is_non_finite());
    let msg = err.to_string();
    assert!(msg.contains("upwind_1d") && msg.contains("step"), "{msg}");
}

#[test]
fn singular_neumann_system_stays_consistent_or_fails_typed() {
    let spec = ProblemSpec::laplacian(12).with_operator(OperatorKind::Neumann);
    let g = exact(spec);
    // The exact gradient of the zero-mean solution map has zero mean.
    assert!(null_space_fraction(&g).unwrap() < 1e-12);
    let problem = Problem::<f64>::new(spec).unwrap();
    assert!(problem.b.sum().abs() < 1e-12, "compatible right-hand side");
    for m in [
        &ImplicitSolve as &dyn GradientMethod<f64>,
        &NaiveUnrolled::default(),
    ] {
        let out = m.run(&problem, tol(1e-10)).unwrap();
        let err = relative_error(&out.gradient, &g).unwrap();
        assert!(err < 1e-9, "{}: {err:e}", m.name());
        assert!(null_space_fraction(&out.gradient).unwrap() < 1e-10);
    }
    // Far past convergence, f64: the projected naive CG stays consistent.
    let k = convergence_iterations(&problem).unwrap();
    let out = NaiveUnrolled::default()
        .run(&problem, Stop::Iterations(5 * k))
        .unwrap();
    assert!(relative_error(&out.gradient, &g).unwrap() < 1e-9);
    assert!(null_space_fraction(&out.gradient).unwrap() < 1e-10);
    // f32: it fails with a typed error naming the op and the iteration.
    let p32 = Problem::<f32>::new(spec).unwrap();
    let err = NaiveUnrolled::default()
        .run(&p32, Stop::Iterations(5 * k))
        .unwrap_err();
    assert!(
        matches!(err, CompareError::NaiveIteration { .. }),
        "{err:?}"
    );
    assert!(err.is_non_finite());
    // The implicit f32 gradient stays finite and accurate there.
    let out = ImplicitSolve.run(&p32, Stop::Iterations(5 * k)).unwrap();
    assert!(relative_error(&out.gradient, &g).unwrap() < 1e-5);
}

#[test]
fn anisotropy_costs_iterations_and_f32_accuracy() {
    let plain = ProblemSpec::laplacian(16);
    let aniso = plain.with_operator(OperatorKind::Anisotropic { ratio: 1e4 });
    let k_plain = convergence_iterations(&Problem::<f64>::new(plain).unwrap()).unwrap();
    let k_aniso = convergence_iterations(&Problem::<f64>::new(aniso).unwrap()).unwrap();
    assert!(k_aniso > 3 * k_plain, "{k_aniso} vs {k_plain}");
    let err = |spec: ProblemSpec| {
        let p = Problem::<f32>::new(spec).unwrap();
        let out = ImplicitSolve.run(&p, tol(1e-5)).unwrap();
        relative_error(&out.gradient, &exact(spec)).unwrap()
    };
    // f32 rounding is amplified by the condition number.
    assert!(err(aniso) > 100.0 * err(plain));
}

#[test]
fn quick_stability_run_writes_its_charts_and_key_figures() {
    let results = run_stability(&StabilityConfig::quick(), &NoProgress).unwrap();
    assert!(results.floors.iter().all(|f| f.holds() == Some(true)));
    // Every failed row carries its error; no row is non-finite without one.
    for r in &results.rows {
        assert!(r.row.finite || r.row.error.is_some(), "{r:?}");
    }
    assert!(results.unroll.iter().all(|u| u.finite || u.error.is_some()));
    let dir = std::env::temp_dir().join(format!("diffphys-stability-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (charts, notes) = write_stability_charts(&dir, &results);
    assert!(notes.is_empty(), "{notes:?}");
    for (file, _) in &charts {
        let svg = std::fs::read_to_string(dir.join(file)).unwrap();
        assert!(svg.starts_with("<svg"), "{file}");
    }
    assert!(charts.len() >= 4);
    let v = stability_key_figures(&results, &dir, 1.0);
    assert_eq!(v["mode"], "stability");
    assert_eq!(v["x0_grad_norm_max"]["implicit"], 0.0);
    assert!(v["naive_first_non_finite_iters"]["f32"].is_u64());
    std::fs::remove_dir_all(&dir).ok();
}
