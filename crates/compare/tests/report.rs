//! Rows serialise with the fields results.json promises, and a tiny sweep produces the
//! table, results.json, report.md and charts.

use diffphys_compare::alloc::CountingAllocator;
use diffphys_compare::harness::{
    compute_floors, run_sweep, write_charts, SweepConfig, TimingPolicy,
};
use diffphys_compare::model::{Method, Precision, ResultRow, RunStatus};
use diffphys_compare::problem::{LossKind, OperatorKind};
use diffphys_compare::progress::NoProgress;
use diffphys_compare::report::{
    read_results_json, render_report, render_table, write_report_md, write_results_json, Report,
};

#[global_allocator]
static HEAP: CountingAllocator = CountingAllocator::new();

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("diffphys-report-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn row_serialises_with_the_documented_fields_and_round_trips() {
    let mut row = ResultRow::new(Method::Naive, Precision::F64, 64, OperatorKind::Laplacian);
    row.iterations = Some(120);
    row.rtol = Some(1e-8);
    row.forward_s = Some(0.5);
    row.backward_s = Some(0.25);
    row.tape_bytes = 1234;
    row.peak_heap_bytes = Some(5678);
    row.grad_rel_err = Some(3e-9);
    let value = serde_json::to_value(&row).unwrap();
    for field in [
        "method",
        "precision",
        "n",
        "iterations",
        "rtol",
        "forward_s",
        "backward_s",
        "tape_bytes",
        "peak_heap_bytes",
        "grad_rel_err",
        "finite",
        "error",
    ] {
        assert!(value.get(field).is_some(), "missing field {field}");
    }
    assert_eq!(value["method"], "naive");
    assert_eq!(value["error"], serde_json::Value::Null);
    let back: ResultRow = serde_json::from_value(value).unwrap();
    assert_eq!(back, row);
    assert_eq!(row.total_s(), Some(0.75));
}

#[test]
fn results_json_round_trips_through_a_file() {
    let dir = temp_dir("json");
    let mut failed = ResultRow::new(
        Method::Implicit,
        Precision::F32,
        8,
        OperatorKind::Anisotropic { ratio: 100.0 },
    );
    failed.error = Some("CG did not converge | 2000 iterations".into());
    failed.status = RunStatus::Failed;
    failed.finite = false;
    let rows = vec![
        ResultRow::new(Method::Exact, Precision::F64, 8, OperatorKind::Laplacian),
        failed,
    ];
    let path = dir.join("results.json");
    write_results_json(&path, &rows).unwrap();
    assert_eq!(read_results_json(&path).unwrap(), rows);
    // The Markdown table escapes the pipe in the error.
    let md = render_report(&Report {
        title: "t",
        configuration: vec![],
        rows: &rows,
        floors: &[],
        charts: vec![],
        notes: vec![],
    });
    assert!(md.contains("did not converge \\| 2000"));
    assert!(md.contains("1 failed, 0 skipped, 1 with non-finite values"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn tiny_sweep_writes_table_json_report_and_charts() {
    let dir = temp_dir("sweep");
    let config = SweepConfig {
        sizes: vec![6, 8],
        iters: vec![3, 12],
        rtols: vec![1e-6],
        max_iters: 500,
        precisions: vec![Precision::F32, Precision::F64],
        operators: vec![OperatorKind::Laplacian],
        loss: LossKind::Tracking,
        fd_max_n: 6,
        naive_tape_limit_bytes: 64 << 20,
        memory_limit_mib: None,
        methods: Method::SELECTABLE.to_vec(),
        timing: TimingPolicy::quick(),
    };
    let rows = run_sweep(&config, Some(&HEAP), &NoProgress).unwrap();
    assert_eq!(rows.len(), config.run_count());
    // Every naive run on these tiny problems succeeds and stays finite.
    let naive: Vec<_> = rows.iter().filter(|r| r.method == Method::Naive).collect();
    assert_eq!(naive.len(), 2 * 2 * 3);
    for r in &naive {
        assert!(r.error.is_none() && r.finite, "{r:?}");
        assert!(r.tape_bytes > 0 && r.forward_s.is_some() && r.backward_s.is_some());
        // Heap figures are process-wide and other tests run in parallel, so only
        // their presence is checked here (tests/alloc.rs checks the counting).
        assert!(r.peak_heap_bytes.is_some());
    }
    // The finite-difference check ran on the f64 6² grid: the naive gradient is
    // the exact derivative of the truncated CG it ran, so it matches to the
    // accuracy of the extrapolated differences (measured ~1e-9..1e-8). In f32 the
    // check is not attempted.
    for r in naive.iter().filter(|r| r.n == 6) {
        match r.precision {
            Precision::F64 => {
                let fd = r.fd_rel_err.unwrap();
                assert!(fd < 1e-6, "{:?}: fd error {fd:e}", r.max_iters);
            }
            _ => assert_eq!(r.fd_rel_err, None),
        }
    }
    assert!(naive
        .iter()
        .filter(|r| r.n == 8)
        .all(|r| r.fd_rel_err.is_none()));
    // Fixed counts run exactly that many iterations.
    assert!(naive
        .iter()
        .filter(|r| r.rtol.is_none())
        .all(|r| r.iterations == r.max_iters));
    let baseline: Vec<_> = rows
        .iter()
        .filter(|r| r.method == Method::BaselineCg)
        .collect();
    assert_eq!(baseline.len(), 4);
    assert!(baseline
        .iter()
        .all(|r| r.reached_relative_residual.unwrap() <= 1e-6 * 1.0001));

    // The exact and implicit methods ran and were compared with the f64 exact
    // gradient; the f64 exact row is its own reference.
    for r in rows
        .iter()
        .filter(|r| r.method == Method::Exact || r.method == Method::Implicit)
    {
        assert!(r.error.is_none(), "{r:?}");
        let err = r.grad_rel_err.unwrap();
        if r.method == Method::Exact && r.precision == Precision::F64 {
            assert_eq!(err, 0.0);
        }
        if r.method == Method::Implicit && r.precision == Precision::F64 && r.rtol == Some(1e-6) {
            assert!(err < 1e-5, "{r:?}");
        }
    }

    let table = render_table(&rows);
    assert!(table.lines().count() == rows.len() + 2);
    assert!(table.starts_with("method"));

    let floors = compute_floors(&rows, None);
    assert_eq!(floors.len(), 9);
    // No 256² run: nothing measured, so nothing fails.
    assert!(floors.iter().all(|f| f.holds().is_none()));

    let (charts, notes) = write_charts(&dir, &rows);
    for (file, _) in &charts {
        let text = std::fs::read_to_string(dir.join(file)).unwrap();
        assert!(text.contains("<svg"), "{file}");
    }
    // Charts without data are notes, not failures.
    assert_eq!(charts.len() + notes.len(), 6, "{charts:?} {notes:?}");
    assert!(charts.iter().any(|(f, _)| f == "iterations_vs_size.svg"));
    assert!(charts.iter().any(|(f, _)| f == "memory_vs_iterations.svg"));

    let report = Report {
        title: "tiny",
        configuration: vec!["sizes: 6, 8".into()],
        rows: &rows,
        floors: &floors,
        charts,
        notes,
    };
    write_report_md(&dir.join("report.md"), &report).unwrap();
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(md.starts_with("# tiny"));
    assert!(md.contains("| method | prec |"));
    assert!(md.contains("![Peak heap vs CG iterations"));
    assert!(md.contains("not measured"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn invalid_configurations_are_typed_errors() {
    let mut c = SweepConfig::quick();
    c.sizes = vec![1];
    assert!(run_sweep(&c, None, &NoProgress).is_err());
    let mut c = SweepConfig::quick();
    c.rtols = vec![2.0];
    assert!(c.validate().is_err());
    let mut c = SweepConfig::quick();
    c.iters.clear();
    c.rtols.clear();
    assert!(c.validate().is_err());
}

#[test]
fn method_precision_operator_and_status_serialise_by_their_names() {
    use serde_json::json;
    for m in Method::SELECTABLE.into_iter().chain([Method::Setup]) {
        assert_eq!(serde_json::to_value(m).unwrap(), json!(m.name()));
    }
    assert_eq!(serde_json::to_value(Precision::F32).unwrap(), json!("f32"));
    for (status, name) in [
        (RunStatus::Ok, "ok"),
        (RunStatus::Failed, "failed"),
        (RunStatus::Skipped, "skipped"),
        (RunStatus::MemoryLimit, "memory_limit"),
    ] {
        assert_eq!(serde_json::to_value(status).unwrap(), json!(name));
        assert_eq!(status.name(), name);
    }
    for op in [
        OperatorKind::Laplacian,
        OperatorKind::Neumann,
        OperatorKind::Anisotropic { ratio: 100.0 },
    ] {
        let v = serde_json::to_value(op).unwrap();
        assert_eq!(v, json!(op.label()));
        assert_eq!(serde_json::from_value::<OperatorKind>(v).unwrap(), op);
    }
    assert!(serde_json::from_value::<OperatorKind>(json!("aniso0.5")).is_err());

    // A row carries its status as written where the run ended; a row of a file
    // from before the field existed reads as failed if it has an error.
    let mut row = ResultRow::new(Method::Naive, Precision::F64, 8, OperatorKind::Laplacian);
    row.error = Some("memory limit: naive on 8×8 cells".into());
    row.status = RunStatus::MemoryLimit;
    let mut value = serde_json::to_value(&row).unwrap();
    assert_eq!(value["status"], "memory_limit");
    assert_eq!(
        serde_json::from_value::<ResultRow>(value.clone()).unwrap(),
        row
    );
    let dir = temp_dir("status");
    let path = dir.join("results.json");
    value.as_object_mut().unwrap().remove("status");
    std::fs::write(&path, json!([value]).to_string()).unwrap();
    assert_eq!(
        read_results_json(&path).unwrap()[0].status,
        RunStatus::Failed
    );
    std::fs::remove_dir_all(dir).unwrap();
}
