//! The MG-PCG implicit gradient against exact, `--methods` selection, and the
//! one warm-up and repetition policy every timed method of a sweep gets.

use std::cell::Cell;

use diffphys_compare::harness::{relative_error, run_sweep, Statistic, SweepConfig, TimingPolicy};
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::implicit::ImplicitSolve;
use diffphys_compare::methods::mgpcg::ImplicitMgpcg;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::model::{Method, Precision, RunStatus};
use diffphys_compare::problem::{OperatorKind, Problem, ProblemSpec};
use diffphys_compare::progress::NoProgress;
use diffphys_compare::CompareError;

fn tol(rtol: f64) -> Stop {
    Stop::Tolerance {
        rtol,
        max_iters: 5_000,
    }
}

#[test]
fn mgpcg_gradient_matches_exact_on_every_operator() {
    // Powers of two and a size that coarsens to an odd grid (24 → 12 → 6 → 3).
    for spec in [
        ProblemSpec::laplacian(32),
        ProblemSpec::laplacian(24),
        ProblemSpec::laplacian(16).with_operator(OperatorKind::Neumann),
        ProblemSpec::laplacian(16).with_operator(OperatorKind::Anisotropic { ratio: 10.0 }),
    ] {
        let problem = Problem::<f64>::new(spec).unwrap();
        let exact = ExactCholesky.run(&problem, Stop::Iterations(0)).unwrap();
        let mg = ImplicitMgpcg::default().run(&problem, tol(1e-10)).unwrap();
        let err = relative_error(&mg.gradient, &exact.gradient).unwrap();
        assert!(err <= 1e-6, "{spec:?}: relative error {err:e}");
        assert!(mg.forward_residual.unwrap() <= 1e-10 * 1.0001, "{spec:?}");
        assert!((mg.loss - exact.loss).abs() <= 1e-9 * exact.loss.abs().max(1.0));
        // Both solves are preconditioned CG runs that met the tolerance.
        assert!(mg.iterations.unwrap() > 0 && mg.adjoint_iterations.unwrap() > 0);
    }
}

#[test]
fn mgpcg_needs_far_fewer_iterations_than_plain_cg_and_hardly_more_on_finer_grids() {
    let iterations = |n: usize, m: &dyn GradientMethod<f64>| {
        let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).unwrap();
        m.run(&problem, tol(1e-8)).unwrap().iterations.unwrap()
    };
    let (cg32, cg64) = (
        iterations(32, &ImplicitSolve),
        iterations(64, &ImplicitSolve),
    );
    let (mg32, mg64) = (
        iterations(32, &ImplicitMgpcg::default()),
        iterations(64, &ImplicitMgpcg::default()),
    );
    // Plain CG's count grows like n; one V-cycle per iteration keeps MG-PCG's
    // nearly flat.
    assert!(cg64 as f64 > 1.5 * cg32 as f64, "plain CG {cg32} → {cg64}");
    assert!(mg64 * 5 < cg64, "MG-PCG {mg64} vs plain CG {cg64} at 64²");
    assert!(mg64 <= mg32 + 3, "MG-PCG {mg32} → {mg64}");
}

#[test]
fn mgpcg_handles_sizes_that_halve_to_odd_grids() {
    // 134 = 2·67: the hierarchy goes 134 → 67 → 34 → 17 → …, with odd levels on
    // the way; iterations stay those of a power of two.
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(134)).unwrap();
    let exact = ExactCholesky.run(&problem, Stop::Iterations(0)).unwrap();
    let mg = ImplicitMgpcg::default().run(&problem, tol(1e-8)).unwrap();
    let err = relative_error(&mg.gradient, &exact.gradient).unwrap();
    assert!(err <= 1e-6, "relative error {err:e}");
    assert!(mg.iterations.unwrap() <= 15, "{:?}", mg.iterations);
    assert!(
        mg.adjoint_iterations.unwrap() <= 15,
        "{:?}",
        mg.adjoint_iterations
    );
}

#[test]
fn methods_parse_by_name_and_bad_names_list_the_valid_ones() {
    for m in Method::SELECTABLE {
        assert_eq!(Method::parse(m.name()).unwrap(), m);
    }
    assert_eq!(
        Method::parse("implicit_mgpcg").unwrap(),
        Method::ImplicitMgpcg
    );
    for bad in ["setup", "mgpcg", "Implicit", ""] {
        let e = Method::parse(bad).unwrap_err().to_string();
        for m in Method::SELECTABLE {
            assert!(e.contains(m.name()), "{bad}: {e}");
        }
    }
}

#[test]
fn policy_runs_warmup_then_repeats_and_reports_the_stated_statistic() {
    // Seconds the successive calls report: the warm-ups are the fastest and
    // must not be picked.
    let script = [0.01, 0.02, 5.0, 3.0, 9.0, 4.0, 7.0];
    for (statistic, want_index, want_s) in [
        (Statistic::Best, 1, 3.0),
        // Timed runs 5, 3, 9, 4, 7: the median is 5, the first timed run.
        (Statistic::Median, 0, 5.0),
    ] {
        let calls = Cell::new(0usize);
        let policy = TimingPolicy {
            warmup: 2,
            repeats: 5,
            statistic,
        };
        let timed = policy
            .run(
                || {
                    let k = calls.get();
                    calls.set(k + 1);
                    Ok((k, script[k]))
                },
                |&(_, s)| s,
            )
            .unwrap();
        assert_eq!(calls.get(), 7, "warm-up + repeats calls");
        assert_eq!(timed.times, vec![5.0, 3.0, 9.0, 4.0, 7.0]);
        assert_eq!(timed.picked, want_index);
        assert_eq!(timed.seconds, want_s);
        // The value is the picked call's own result.
        assert_eq!(timed.value, (2 + want_index, want_s));
    }
    // An even count takes the lower median.
    assert_eq!(Statistic::Median.pick(&[4.0, 1.0, 3.0, 2.0]), Some(3));
    assert_eq!(Statistic::Best.pick(&[]), None);
}

#[test]
fn policy_stops_at_the_first_failure_and_needs_a_timed_run() {
    let calls = Cell::new(0usize);
    let e = TimingPolicy::default()
        .run(
            || {
                calls.set(calls.get() + 1);
                if calls.get() == 2 {
                    Err(CompareError::invalid("second run fails"))
                } else {
                    Ok(1.0)
                }
            },
            |&s| s,
        )
        .unwrap_err();
    assert!(e.to_string().contains("second run fails"));
    assert_eq!(calls.get(), 2);
    let none = TimingPolicy {
        repeats: 0,
        ..TimingPolicy::default()
    };
    assert!(matches!(
        none.run(|| Ok(1.0), |&s| s),
        Err(CompareError::InvalidArgument(_))
    ));
}

#[test]
fn every_timed_method_of_a_sweep_gets_the_same_policy() {
    for statistic in [Statistic::Best, Statistic::Median] {
        let config = SweepConfig {
            sizes: vec![8],
            iters: vec![4],
            rtols: vec![1e-8],
            precisions: vec![Precision::F64],
            operators: vec![OperatorKind::Laplacian],
            fd_max_n: 0,
            methods: Method::SELECTABLE.to_vec(),
            timing: TimingPolicy {
                warmup: 2,
                repeats: 3,
                statistic,
            },
            ..SweepConfig::quick()
        };
        let rows = run_sweep(&config, None, &NoProgress).unwrap();
        assert_eq!(rows.len(), config.run_count());
        for m in Method::SELECTABLE {
            assert!(rows.iter().any(|r| r.method == m), "no {m} row");
        }
        for r in &rows {
            assert!(r.error.is_none(), "{r:?}");
            assert_eq!(r.warmup_runs, 2, "{} warm-up", r.method);
            assert_eq!(r.run_times_s.len(), 3, "{} timed runs", r.method);
            // The row's time is the picked run's, by the stated statistic.
            let i = statistic.pick(&r.run_times_s).unwrap();
            assert_eq!(r.total_s().unwrap(), r.run_times_s[i], "{}", r.method);
        }
    }
}

#[test]
fn a_sweep_runs_only_the_selected_methods() {
    let config = SweepConfig {
        sizes: vec![8, 16],
        precisions: vec![Precision::F64],
        methods: vec![Method::ImplicitMgpcg, Method::Naive],
        ..SweepConfig::quick()
    };
    let rows = run_sweep(&config, None, &NoProgress).unwrap();
    assert_eq!(rows.len(), config.run_count());
    assert_eq!(rows.len(), 2 * 2 * config.stops().len());
    assert!(rows
        .iter()
        .all(|r| matches!(r.method, Method::ImplicitMgpcg | Method::Naive)));
    // The exact gradient is still the error reference without an exact row.
    assert!(rows.iter().all(|r| r.grad_rel_err.is_some()), "{rows:?}");
    // Naive tolerance runs are sized without an implicit run to count for them.
    assert!(rows.iter().all(|r| r.error.is_none()), "{rows:?}");

    let empty = SweepConfig {
        methods: vec![],
        ..SweepConfig::quick()
    };
    assert!(matches!(
        run_sweep(&empty, None, &NoProgress),
        Err(CompareError::InvalidArgument(_))
    ));
    let setup = SweepConfig {
        methods: vec![Method::Setup],
        ..SweepConfig::quick()
    };
    assert!(matches!(
        run_sweep(&setup, None, &NoProgress),
        Err(CompareError::InvalidArgument(_))
    ));
}

/// The binary, as CI runs it.
fn harness() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_diffphys-compare"))
}

/// Runs `command`, asserts that it succeeded, and returns its stdout and the
/// JSON of its last non-empty line.
fn run_ok(command: &mut std::process::Command) -> (String, serde_json::Value) {
    let out = command.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let last = stdout.lines().rfind(|l| !l.trim().is_empty()).unwrap();
    let tail = serde_json::from_str(last).unwrap();
    (stdout, tail)
}

#[test]
fn the_command_line_rejects_unknown_methods_listing_the_valid_ones() {
    let out = harness()
        .args(["--methods", "implicit,bogus"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(64));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bogus"), "{err}");
    for m in Method::SELECTABLE {
        assert!(err.contains(m.name()), "{err}");
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let tail: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(tail["ok"], false);
}

#[test]
fn quick_run_with_selected_methods_ends_with_their_keys_and_the_policy() {
    let dir = std::env::temp_dir().join(format!("diffphys-cli-methods-{}", std::process::id()));
    let (stdout, tail) = run_ok(
        harness()
            .args(["--quick", "--methods", "implicit_mgpcg,exact", "--out"])
            .arg(&dir),
    );
    assert!(stdout.contains("timing: 1 untimed warm-up run, then 1 timed run"));
    let methods = tail["methods"].as_object().unwrap();
    let names: Vec<&str> = methods.keys().map(String::as_str).collect();
    assert_eq!(names.len(), 2, "{names:?}");
    let mg = &tail["methods"]["implicit_mgpcg"];
    assert_eq!(mg["runs"], mg["ok"], "{mg}");
    assert!(mg["worst_grad_rel_err"].as_f64().unwrap() < 1e-3, "{mg}");
    assert!(mg["max_iterations"].as_u64().unwrap() > 0);
    assert_eq!(tail["timing"]["warmup"], 1);
    assert_eq!(tail["timing"]["repeats"], 1);
    assert_eq!(tail["timing"]["statistic"], "best");
    for key in [
        "mgpcg_max_iterations",
        "mgpcg_grad_err",
        "mgpcg_speedup_vs_exact",
    ] {
        assert!(tail["floors"].get(key).is_some(), "{key}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn naive_alone_is_sized_by_a_plain_solve_stopped_at_the_tape_limit() {
    // 32² in f64: 7 arrays of 8 KiB per unrolled iteration; room for 10.
    let per_iteration = 7 * 32 * 32 * 8;
    let config = SweepConfig {
        sizes: vec![32],
        iters: vec![],
        rtols: vec![1e-8],
        precisions: vec![Precision::F64],
        methods: vec![Method::Naive],
        naive_tape_limit_bytes: 10 * per_iteration,
        ..SweepConfig::quick()
    };
    let rows = run_sweep(&config, None, &NoProgress).unwrap();
    assert_eq!(rows.len(), 1);
    let r = &rows[0];
    assert_eq!(r.status, RunStatus::Skipped);
    // Plain CG needs far more than 11 iterations at 32²; the count stopped there.
    let e = r.error.as_deref().unwrap();
    assert!(e.contains("at least 11 unrolled iterations"), "{e}");
}

/// Runs the quick sweep with every array split across `threads` threads and
/// returns its results.json rows and its JSON tail.
fn quick_rows_on(threads: usize) -> (Vec<serde_json::Value>, serde_json::Value) {
    let dir = std::env::temp_dir().join(format!(
        "diffphys-cli-threads-{threads}-{}",
        std::process::id()
    ));
    let (_, tail) = run_ok(
        harness()
            .args(["--quick", "--methods", "implicit,naive,implicit_mgpcg"])
            .args(["--threads", &threads.to_string(), "--parallel-min-len", "1"])
            .arg("--out")
            .arg(&dir),
    );
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("results.json")).unwrap()).unwrap();
    std::fs::remove_dir_all(dir).unwrap();
    let rows = results["rows"]
        .as_array()
        .or_else(|| results.as_array())
        .expect("results.json holds the rows")
        .clone();
    (rows, tail)
}

#[test]
fn the_thread_count_changes_no_result_of_the_harness() {
    let (one, tail_one) = quick_rows_on(1);
    let (three, tail_three) = quick_rows_on(3);
    assert_eq!(tail_one["threads"], 1);
    assert_eq!(tail_three["threads"], 3);
    assert_eq!(tail_one["parallel_min_len"], 1);
    assert_eq!(one.len(), three.len());
    assert!(!one.is_empty());
    let mut compared = 0;
    for (a, b) in one.iter().zip(&three) {
        assert_eq!(a["method"], b["method"]);
        // Every array was split across the threads (threshold 1), and the
        // chunked reductions make the numbers bitwise equal.
        for key in [
            "loss",
            "grad_rel_err",
            "iterations",
            "reached_relative_residual",
        ] {
            assert_eq!(
                a[key], b[key],
                "{key} of {} differs: {a} vs {b}",
                a["method"]
            );
            compared += usize::from(!a[key].is_null());
        }
    }
    assert!(compared > 0);
}
