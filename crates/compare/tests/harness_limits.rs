//! The harness's `.npy` output reads back bit for bit, and sizes the machine
//! cannot hold (or grids too small for a run) become rows with a typed error
//! instead of aborting the process.

use diffphys_compare::harness::{run_sweep, run_sweep_npy, stop_label, SweepConfig};
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::implicit::ImplicitSolve;
use diffphys_compare::methods::mgpcg::ImplicitMgpcg;
use diffphys_compare::methods::naive::NaiveUnrolled;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::model::{Method, Precision, RunStatus};
use diffphys_compare::npy::{NpyEntry, NpyWriter};
use diffphys_compare::problem::{OperatorKind, Problem, ProblemSpec};
use diffphys_compare::progress::NoProgress;
use ndarray::{Array2, ArrayD};
use ndarray_npy::read_npy;

fn sweep_config(sizes: Vec<usize>) -> SweepConfig {
    SweepConfig {
        sizes,
        iters: vec![5],
        rtols: vec![1e-8],
        precisions: vec![Precision::F64],
        operators: vec![OperatorKind::Laplacian],
        fd_max_n: 0,
        ..SweepConfig::quick()
    }
}

fn same_bits(path: &std::path::Path, expected: &Array2<f64>) {
    let back: ArrayD<f64> = read_npy(path).unwrap();
    assert_eq!(back.shape(), expected.shape(), "{}", path.display());
    assert!(
        back.iter()
            .zip(expected)
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "{} differs",
        path.display()
    );
}

#[test]
fn harness_npy_reads_back_bit_for_bit() {
    let dir = std::env::temp_dir().join(format!("diffphys-harness-npy-{}", std::process::id()));
    let config = sweep_config(vec![8]);
    let mut npy = NpyWriter::new(&dir).unwrap();
    let rows = run_sweep_npy(&config, None, &NoProgress, &mut npy).unwrap();
    assert!(rows.iter().all(|r| r.error.is_none()), "{rows:?}");
    let index = npy.finish().unwrap();

    let problem = Problem::<f64>::new(ProblemSpec::laplacian(8)).unwrap();
    same_bits(&dir.join("n8_b.npy"), &problem.b);
    same_bits(&dir.join("n8_target.npy"), &problem.target);
    let exact = ExactCholesky.run(&problem, Stop::Iterations(0)).unwrap();
    same_bits(&dir.join("n8_grad_exact.npy"), &exact.gradient);
    let mut names = vec!["n8_b", "n8_target", "n8_grad_exact"]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
    for stop in config.stops() {
        let implicit = ImplicitSolve.run(&problem, stop).unwrap();
        let mgpcg = ImplicitMgpcg::default().run(&problem, stop).unwrap();
        let naive = NaiveUnrolled::default().run(&problem, stop).unwrap();
        for (method, gradient) in [
            ("implicit", implicit.gradient),
            ("implicit_mgpcg", mgpcg.gradient),
            ("naive", naive.gradient),
        ] {
            let name = format!("n8_grad_{method}_{}", stop_label(stop));
            same_bits(&dir.join(format!("{name}.npy")), &gradient);
            names.push(name);
        }
    }
    let entries: Vec<NpyEntry> =
        serde_json::from_str(&std::fs::read_to_string(index).unwrap()).unwrap();
    let mut listed: Vec<_> = entries.iter().map(|e| e.name.clone()).collect();
    listed.sort();
    names.sort();
    assert_eq!(listed, names);
    assert!(entries
        .iter()
        .all(|e| e.dtype == "float64" && e.shape == [8, 8]));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn sizes_over_the_memory_limit_are_refused_rows_and_the_others_run() {
    let mut config = sweep_config(vec![8, 100_000]);
    config.memory_limit_mib = Some(64);
    let rows = run_sweep(&config, None, &NoProgress).unwrap();
    assert_eq!(rows.len(), config.run_count());
    for r in rows.iter().filter(|r| r.n == 8) {
        assert!(r.error.is_none(), "{r:?}");
    }
    let big: Vec<_> = rows.iter().filter(|r| r.n == 100_000).collect();
    assert_eq!(big.len(), rows.len() / 2);
    for r in &big {
        let e = r.error.as_deref().unwrap();
        assert!(
            r.status == RunStatus::MemoryLimit
                && e.contains(r.method.name())
                && e.contains("100000"),
            "{e}"
        );
    }
    // A limit below a small grid's naive tape refuses only the naive runs.
    let mut config = sweep_config(vec![32]);
    config.iters = vec![300];
    config.rtols.clear();
    config.memory_limit_mib = Some(1);
    let rows = run_sweep(&config, None, &NoProgress).unwrap();
    let naive = rows.iter().find(|r| r.method == Method::Naive).unwrap();
    assert!(naive
        .error
        .as_deref()
        .unwrap()
        .starts_with("memory limit: naive on 32×32"));
    let implicit = rows.iter().find(|r| r.method == Method::Implicit).unwrap();
    assert!(implicit.error.is_none(), "{implicit:?}");
}

#[test]
fn grids_too_small_for_a_fixed_count_are_a_typed_row() {
    for n in [2, 3] {
        let mut config = sweep_config(vec![n]);
        config.iters = vec![5, 30];
        let rows = run_sweep(&config, None, &NoProgress).unwrap();
        let naive: Vec<_> = rows.iter().filter(|r| r.method == Method::Naive).collect();
        // 5 ≤ 9 runs on 3², not on 2²; 30 exceeds both; the tolerance run converges.
        for r in naive {
            let too_many = r.max_iters.is_some_and(|k| r.rtol.is_none() && k > n * n);
            match &r.error {
                Some(e) => assert!(too_many && e.starts_with("grid too small: "), "{e}"),
                None => assert!(!too_many && r.finite, "{r:?}"),
            }
        }
    }
}
