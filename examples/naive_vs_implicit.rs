//! Naive vs implicit gradients through conjugate gradient on one scene, through the
//! library API of `diffphys-compare` (the harness's code path, one problem only).
//!
//! The scene: `p = A⁻¹ b` with `A = −∇²` on `n × n` cells of `[0, 1]²` (zero
//! Dirichlet walls), `L = ½‖p − p*‖²`, gradient with respect to `b`. Three
//! methods: naive (CG unrolled on the tape), implicit (the Poisson op, one
//! adjoint CG solve) and exact (sparse Cholesky, f64, the reference). First both
//! CG methods solve to relative tolerance 1e-8 and are measured (times, tape
//! bytes, peak heap, error against exact); then both run a few fixed iteration
//! counts below convergence, where the naive gradient is the exact derivative of
//! a truncated, nonlinear iteration and far from `A⁻¹(p − p*)`.
//!
//! Tutorial: docs/04-naive-vs-implicit.md. Run:
//! `cargo run --release --example naive_vs_implicit` (n = 64; `-- --small` for
//! n = 16, `-- --out DIR` for the chart, default `out/naive_vs_implicit/`).

mod common;

use diffphys::report::chart::{line_chart_svg, LineChart, Series};
use diffphys_compare::alloc::CountingAllocator;
use diffphys_compare::harness::measure;
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::implicit::ImplicitSolve;
use diffphys_compare::methods::naive::NaiveUnrolled;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::model::{Method, ResultRow};
use diffphys_compare::problem::{Problem, ProblemSpec};
use diffphys_compare::report::render_table;

type BoxError = Box<dyn std::error::Error>;

/// Counts heap bytes so `measure` can report each run's peak.
#[global_allocator]
static HEAP: CountingAllocator = CountingAllocator::new();

/// The tolerance of the harness's floors.
const RTOL: f64 = 1e-8;

/// `a / b`, or NaN if either is missing or `b` is zero.
fn ratio(a: Option<f64>, b: Option<f64>) -> f64 {
    match (a, b) {
        (Some(a), Some(b)) if b != 0.0 => a / b,
        _ => f64::NAN,
    }
}

/// A JSON number, or `null` for a missing or non-finite figure.
fn json_f64(v: Option<f64>) -> serde_json::Value {
    v.filter(|v| v.is_finite())
        .map_or(serde_json::Value::Null, |v| v.into())
}

/// Naive vs implicit gradients through conjugate gradient on one scene.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    common: common::ExampleArgs,
}

fn main() -> Result<(), BoxError> {
    let Cli { common: args } = common::parse_args("naive_vs_implicit")?;
    let n = args.pick(64, 16);
    let fixed_counts: Vec<usize> = args.pick(vec![5, 10, 20, 50, 100], vec![5, 10, 20]);

    // One scene, one f64 reference gradient: A⁻¹(p − p*) by sparse Cholesky.
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n))?;
    let exact = ExactCholesky.run(&problem, Stop::Iterations(0))?.gradient;

    let naive = NaiveUnrolled::default();
    let methods: [&dyn GradientMethod<f64>; 2] = [&naive, &ImplicitSolve];
    let measure_all = |stop: Stop| -> Vec<ResultRow> {
        methods
            .iter()
            .map(|m| measure(*m, &problem, Some(stop), Some(&HEAP), Some(&exact)).0)
            .collect()
    };

    // Both CG methods to the floors' tolerance.
    let converged = measure_all(Stop::Tolerance {
        rtol: RTOL,
        max_iters: 20_000,
    });
    let [naive_row, implicit_row] = [&converged[0], &converged[1]];
    for row in [naive_row, implicit_row] {
        if let Some(e) = &row.error {
            return Err(format!("{} failed at rtol {RTOL:e}: {e}", row.method).into());
        }
    }

    // Fixed iteration counts below convergence: the truncated iteration.
    let truncated: Vec<ResultRow> = fixed_counts
        .iter()
        .flat_map(|&k| measure_all(Stop::Iterations(k)))
        .collect();

    println!(
        "{n}×{n} cells, A = −∇², L = ½‖p − p*‖², gradient wrt b; errors vs exact (f64 Cholesky)"
    );
    println!(
        "{}",
        render_table(&[converged.clone(), truncated.clone()].concat())
    );

    let tape_ratio = naive_row.tape_bytes as f64 / implicit_row.tape_bytes as f64;
    let heap_ratio = ratio(
        implicit_row.peak_heap_bytes.map(|b| b as f64),
        naive_row.peak_heap_bytes.map(|b| b as f64),
    );
    let time_ratio = ratio(implicit_row.total_s(), naive_row.total_s());
    println!(
        "at rtol {RTOL:e}: naive tape / implicit tape = {tape_ratio:.1}; implicit / naive peak \
         heap = {heap_ratio:.4}, gradient time = {time_ratio:.3}; gradient errors vs exact: \
         naive {:.2e}, implicit {:.2e}",
        naive_row.grad_rel_err.unwrap_or(f64::NAN),
        implicit_row.grad_rel_err.unwrap_or(f64::NAN),
    );
    for row in [naive_row, implicit_row] {
        match row.grad_rel_err {
            Some(e) if e <= 1e-6 => {}
            other => {
                return Err(format!(
                    "{} gradient error {other:?} at rtol {RTOL:e}: expected ≤ 1e-6",
                    row.method
                )
                .into())
            }
        }
    }

    // Gradient error against the fixed iteration count, one curve per method
    // (a non-finite gradient is drawn as a cross).
    let curve = |method: Method| -> Vec<(f64, f64)> {
        truncated
            .iter()
            .filter(|r| r.method == method)
            .map(|r| {
                let k = r.max_iters.unwrap_or(0) as f64;
                (k, r.grad_rel_err.unwrap_or(f64::NAN))
            })
            .collect()
    };
    let errors_of = |method: Method| -> Vec<serde_json::Value> {
        curve(method)
            .iter()
            .map(|&(_, e)| json_f64(Some(e)))
            .collect()
    };
    let title = format!("Gradient error vs fixed CG iterations ({n}², laplacian, f64)");
    let chart = args.out.join("error_vs_iterations.svg");
    line_chart_svg(
        &chart,
        &LineChart {
            title: &title,
            x_label: "CG iterations",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &[
                Series::new("naive f64", curve(Method::Naive)),
                Series::new("implicit f64", curve(Method::Implicit)),
            ],
        },
    )?;
    println!("chart written to {}", chart.display());

    if args.npy {
        let stop = Stop::Tolerance {
            rtol: RTOL,
            max_iters: 20_000,
        };
        let naive_grad = naive.run(&problem, stop)?.gradient.into_dyn();
        let implicit_grad = ImplicitSolve.run(&problem, stop)?.gradient.into_dyn();
        let (b, target, exact) = (
            problem.b.clone().into_dyn(),
            problem.target.clone().into_dyn(),
            exact.clone().into_dyn(),
        );
        args.write_npy(&[
            (
                "b",
                b.view(),
                "the right-hand side, the leaf of the gradient [n, n]",
            ),
            (
                "target",
                target.view(),
                "the target potential p* of the loss ½‖p − p*‖² [n, n]",
            ),
            (
                "grad_exact",
                exact.view(),
                "∂L/∂b by sparse Cholesky [n, n]",
            ),
            (
                "grad_naive",
                naive_grad.view(),
                "∂L/∂b through CG unrolled on the tape, rtol 1e-8",
            ),
            (
                "grad_implicit",
                implicit_grad.view(),
                "∂L/∂b by one adjoint CG solve, rtol 1e-8",
            ),
        ])?;
    }

    common::print_json_line(&serde_json::json!({
        "example": "naive_vs_implicit",
        "n": n,
        "rtol": RTOL,
        "iterations_naive": naive_row.iterations,
        "iterations_implicit_forward": implicit_row.iterations,
        "iterations_implicit_adjoint": implicit_row.adjoint_iterations,
        "grad_rel_err_naive": json_f64(naive_row.grad_rel_err),
        "grad_rel_err_implicit": json_f64(implicit_row.grad_rel_err),
        "tape_bytes_naive": naive_row.tape_bytes,
        "tape_bytes_implicit": implicit_row.tape_bytes,
        "tape_ratio_naive_over_implicit": json_f64(Some(tape_ratio)),
        "peak_heap_ratio_implicit_over_naive": json_f64(Some(heap_ratio)),
        "time_ratio_implicit_over_naive": json_f64(Some(time_ratio)),
        "fixed_iterations": fixed_counts,
        "fixed_grad_rel_err_naive": errors_of(Method::Naive),
        "fixed_grad_rel_err_implicit": errors_of(Method::Implicit),
    }));
    Ok(())
}
