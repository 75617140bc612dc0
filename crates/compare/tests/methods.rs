//! The gradient methods agree with each other and with an independent reference
//! on small problems, and fail loudly where they fail.

use diffphys_compare::methods::baseline::{baseline_cg, StraightforwardLaplacian};
use diffphys_compare::methods::naive::NaiveUnrolled;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::problem::{LossKind, OperatorKind, Problem, ProblemSpec};
use ndarray::Array2;

/// `∂L/∂b = A⁻¹ ∂L/∂p` with both solves by the straightforward CG to 1e-13: a
/// reference that shares no code with the tape or the ops crate's solver.
fn reference_gradient(problem: &Problem<f64>) -> Array2<f64> {
    let a = StraightforwardLaplacian::negative(&problem.grid);
    let stop = Stop::Tolerance {
        rtol: 1e-13,
        max_iters: 10_000,
    };
    let solve = |rhs: &Array2<f64>| {
        let mut x = vec![0.0; rhs.len()];
        baseline_cg(&a, rhs.as_slice().unwrap(), &mut x, stop).unwrap();
        Array2::from_shape_vec(rhs.raw_dim(), x).unwrap()
    };
    let p = solve(&problem.b);
    solve(&problem.loss_gradient(&p))
}

fn rel_err(g: &Array2<f64>, want: &Array2<f64>) -> f64 {
    let num: f64 = g.iter().zip(want).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = want.iter().map(|b| b * b).sum();
    (num / den).sqrt()
}

#[test]
fn naive_gradient_matches_the_reference_on_8x8() {
    for spec in [
        ProblemSpec::laplacian(8),
        ProblemSpec::laplacian(8).with_loss(LossKind::Weighted),
        ProblemSpec::laplacian(8).with_operator(OperatorKind::Anisotropic { ratio: 100.0 }),
    ] {
        let problem = Problem::<f64>::new(spec).unwrap();
        let stop = Stop::Tolerance {
            rtol: 1e-12,
            max_iters: 500,
        };
        let out = NaiveUnrolled::default().run(&problem, stop).unwrap();
        let err = rel_err(&out.gradient, &reference_gradient(&problem));
        assert!(err < 1e-9, "{spec:?}: naive vs reference {err:e}");
        assert!(out.forward_residual.unwrap() <= 1e-12);
        assert!(out.tape_bytes > 0);
    }
}

#[test]
fn naive_past_convergence_in_f32_fails_naming_op_and_iteration() {
    use diffphys_compare::CompareError;
    use diffphys_tape::{Pass, TapeError};
    let problem = Problem::<f32>::new(ProblemSpec::laplacian(8)).unwrap();
    // 64 unknowns: CG converges (to f32 rounding) in well under 64 iterations;
    // 100 more divide by residual norms that underflow.
    let err = NaiveUnrolled::default()
        .run(&problem, Stop::Iterations(100))
        .unwrap_err();
    match &err {
        CompareError::NaiveIteration {
            iteration,
            source: TapeError::NonFinite { op, pass, .. },
        } => {
            assert_eq!(*pass, Pass::Backward);
            assert_eq!(op, "div", "β = ‖r‖²/‖r_prev‖² or α = ‖r‖²/<p, Ap>");
            assert!((30..100).contains(iteration), "iteration {iteration}");
        }
        other => panic!("expected a naive iteration error, got {other:?}"),
    }
    assert!(err.to_string().contains("iteration"));
    assert!(err.is_non_finite());

    // With the check off the same run completes and the NaN is in the gradient.
    let unchecked = NaiveUnrolled {
        check_finite: false,
    };
    let out = unchecked.run(&problem, Stop::Iterations(100)).unwrap();
    assert!(out.gradient.iter().any(|g| !g.is_finite()));
    // Stopped at convergence, the f32 naive gradient is fine.
    let stop = Stop::Tolerance {
        rtol: 1e-5,
        max_iters: 100,
    };
    let ok = NaiveUnrolled::default().run(&problem, stop).unwrap();
    let reference = reference_gradient(&Problem::<f64>::new(ProblemSpec::laplacian(8)).unwrap());
    let g64 = ok.gradient.mapv(f64::from);
    assert!(rel_err(&g64, &reference) < 1e-4);
}

#[test]
fn exact_matches_the_independent_reference() {
    use diffphys_compare::methods::exact::ExactCholesky;
    for spec in [
        ProblemSpec::laplacian(8),
        ProblemSpec::laplacian(8).with_operator(OperatorKind::Anisotropic { ratio: 100.0 }),
    ] {
        let problem = Problem::<f64>::new(spec).unwrap();
        let out = ExactCholesky.run(&problem, Stop::Iterations(0)).unwrap();
        let err = rel_err(&out.gradient, &reference_gradient(&problem));
        // Both are accurate to ~ε·κ; the CG reference stops at 1e-13.
        assert!(err < 1e-10, "{spec:?}: exact vs reference {err:e}");
        assert_eq!(out.tape_bytes, 0);
        assert!(out.forward_residual.unwrap() < 1e-13);
    }
}

#[test]
fn naive_and_implicit_agree_with_exact_on_8x8() {
    use diffphys_compare::harness::relative_error;
    use diffphys_compare::methods::exact::ExactCholesky;
    use diffphys_compare::methods::implicit::ImplicitSolve;
    for spec in [
        ProblemSpec::laplacian(8),
        ProblemSpec::laplacian(8).with_loss(LossKind::Weighted),
        ProblemSpec::laplacian(8).with_operator(OperatorKind::Anisotropic { ratio: 100.0 }),
    ] {
        let p64 = Problem::<f64>::new(spec).unwrap();
        let exact = ExactCholesky
            .run(&p64, Stop::Iterations(0))
            .unwrap()
            .gradient;
        let stop = Stop::Tolerance {
            rtol: 1e-10,
            max_iters: 1000,
        };
        let naive = NaiveUnrolled::default().run(&p64, stop).unwrap();
        let implicit = ImplicitSolve.run(&p64, stop).unwrap();
        let e_naive = relative_error(&naive.gradient, &exact).unwrap();
        let e_implicit = relative_error(&implicit.gradient, &exact).unwrap();
        assert!(e_naive < 1e-8, "{spec:?}: naive {e_naive:e}");
        assert!(e_implicit < 1e-8, "{spec:?}: implicit {e_implicit:e}");
        // The implicit tape holds b, p and the loss's arrays, not the iterates.
        assert!(implicit.adjoint_iterations.unwrap() > 0);
        assert!(implicit.tape_bytes * 10 < naive.tape_bytes);
        // Same CG, same data: the same number of forward iterations (±restart).
        let (a, b) = (naive.iterations.unwrap(), implicit.iterations.unwrap());
        assert!(a.abs_diff(b) <= 2, "naive {a} vs implicit {b} iterations");
        // The losses agree too: both solved to 1e-10.
        assert!((naive.loss - implicit.loss).abs() <= 1e-8 * naive.loss.abs());

        // f32: both within f32 accuracy of the f64 exact gradient at a
        // tolerance f32 can reach.
        let p32 = Problem::<f32>::new(spec).unwrap();
        let stop = Stop::Tolerance {
            rtol: 1e-5,
            max_iters: 1000,
        };
        let naive = NaiveUnrolled::default().run(&p32, stop).unwrap();
        let implicit = ImplicitSolve.run(&p32, stop).unwrap();
        let e_naive = relative_error(&naive.gradient, &exact).unwrap();
        let e_implicit = relative_error(&implicit.gradient, &exact).unwrap();
        assert!(e_naive < 1e-3, "{spec:?} f32: naive {e_naive:e}");
        assert!(e_implicit < 1e-3, "{spec:?} f32: implicit {e_implicit:e}");
    }
}

#[test]
fn fixed_iterations_truncate_both_methods_alike_in_the_forward() {
    use diffphys_compare::methods::implicit::ImplicitSolve;
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(16)).unwrap();
    let naive = NaiveUnrolled::default()
        .run(&problem, Stop::Iterations(5))
        .unwrap();
    let implicit = ImplicitSolve.run(&problem, Stop::Iterations(5)).unwrap();
    assert_eq!(naive.iterations, Some(5));
    assert_eq!(implicit.iterations, Some(5));
    // Same five CG steps: the same solution, hence the same loss and residual.
    let (ra, rb) = (
        naive.forward_residual.unwrap(),
        implicit.forward_residual.unwrap(),
    );
    assert!((ra - rb).abs() <= 1e-10 * ra, "{ra:e} vs {rb:e}");
    assert!((naive.loss - implicit.loss).abs() <= 1e-10 * naive.loss.abs());
    // …but different gradients: naive differentiates the truncated iteration,
    // implicit evaluates A⁻¹ ∂L/∂p with a truncated adjoint solve.
    let diff = rel_err(&naive.gradient, &implicit.gradient);
    assert!(diff > 1e-3, "gradients unexpectedly close: {diff:e}");
}

/// The naive tape holds seven grid arrays per CG iteration (`A p`, `α p`,
/// `x`, `α A p`, `r`, `β p`, `p`) plus its scalars (`<p, A p>`, `α`, `‖r‖²`,
/// `β`), so its bytes grow linearly in the iteration count, by between 7 arrays
/// and 7 arrays + 8 scalars per iteration; the implicit tape holds the same
/// few arrays whatever the count.
#[test]
fn naive_tape_grows_seven_arrays_per_iteration_and_implicit_does_not() {
    use diffphys_compare::harness::naive_bytes_per_iteration;
    use diffphys_compare::methods::implicit::ImplicitSolve;
    let n = 16;
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).unwrap();
    let scalar = std::mem::size_of::<f64>();
    let array = n * n * scalar;
    assert_eq!(naive_bytes_per_iteration::<f64>(n), 7 * array);
    let counts = [10, 20, 40];
    let tape =
        |m: &dyn GradientMethod<f64>, k| m.run(&problem, Stop::Iterations(k)).unwrap().tape_bytes;
    let naive: Vec<usize> = counts
        .iter()
        .map(|&k| tape(&NaiveUnrolled::default(), k))
        .collect();
    let implicit: Vec<usize> = counts.iter().map(|&k| tape(&ImplicitSolve, k)).collect();
    for (a, b) in [(0, 1), (1, 2)] {
        let per_iteration = (naive[b] - naive[a]) / (counts[b] - counts[a]);
        assert!(
            (7 * array..=7 * array + 8 * scalar).contains(&per_iteration),
            "naive: {per_iteration} bytes per iteration, {array} per array ({naive:?})"
        );
    }
    assert!(
        implicit.iter().all(|&b| b == implicit[0]),
        "implicit tape depends on the iteration count: {implicit:?}"
    );
    assert!(implicit[0] < 7 * array, "{implicit:?}");
}

/// A tolerance below f32's rounding floor is measured, not failed, and its row
/// carries the residual reached; f64 reaches the same tolerance; a solve that
/// runs into the iteration cap is still a failed row.
#[test]
fn tolerance_rows_report_the_residual_reached() {
    use diffphys_compare::harness::measure;
    use diffphys_compare::methods::implicit::ImplicitSolve;
    let stop = |max_iters| Stop::Tolerance {
        rtol: 1e-8,
        max_iters,
    };
    let spec = ProblemSpec::laplacian(64);
    let (row, _) = measure(
        &ImplicitSolve,
        &Problem::<f32>::new(spec).unwrap(),
        Some(stop(20_000)),
        None,
        None,
    );
    assert!(row.error.is_none(), "{row:?}");
    assert_eq!(row.rtol, Some(1e-8));
    let reached = row.reached_relative_residual.unwrap();
    assert!(reached > 1e-6, "f32 at 64² cannot reach 1e-8: {reached:e}");
    let (row, _) = measure(
        &ImplicitSolve,
        &Problem::<f64>::new(spec).unwrap(),
        Some(stop(20_000)),
        None,
        None,
    );
    let reached = row.reached_relative_residual.unwrap();
    assert!(reached <= 1.01e-8, "f64 reaches 1e-8: {reached:e}");
    let (row, _) = measure(
        &ImplicitSolve,
        &Problem::<f64>::new(spec).unwrap(),
        Some(stop(5)),
        None,
        None,
    );
    let error = row.error.unwrap_or_default();
    assert!(
        error.contains("did not converge in 5 iterations"),
        "{error}"
    );
}
