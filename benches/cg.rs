//! Conjugate gradient on `A = −∇²` (zero Dirichlet walls, the scene of
//! `diffphys-compare`): iteration throughput of the fused solver against the
//! straightforward one, and the cost of a gradient through the solve, naive
//! against implicit.
//!
//! - `cg/iteration`: a fixed number of CG iterations from `x = 0` at 64² to
//!   1024², with `fused` ([`conjugate_gradient`], the solver of the implicit
//!   path: stencil fused with `<p, A p>`, boundary outside the inner loop) and
//!   `baseline` ([`baseline_cg`], one loop per vector operation, the boundary
//!   tested at every cell). Throughput is cells × iterations per sample, so the
//!   report reads as cells per second of one CG iteration. `fused_1_thread` is
//!   `fused` on a one-thread pool (`diffphys::tape::parallel::with_threads`):
//!   the ratio to `fused` is what the second core brings (kernels split arrays
//!   from `parallel::min_parallel_len()` cells, 2¹⁸ by default).
//! - `cg/gradient`: the whole gradient `∂L/∂b` of `L = ½‖A⁻¹b − p*‖²` (forward
//!   solve, loss, backward), CG to relative tolerance 1e-8, `naive` (CG unrolled
//!   on the tape) and `implicit` (the Poisson op, one adjoint solve), at 64² and
//!   128², f64. Throughput is cells per gradient.
//!
//! Run: `cargo bench --bench cg` (a few minutes on two cores; `-- --quick` for a
//! shorter run, `-- cg/iteration` or `-- cg/gradient` for one group). Before
//! timing, each size checks that the two CG variants agree and prints the tape
//! bytes and the error against the exact (sparse Cholesky) gradient of both
//! gradient methods, the accuracy the times are bought at.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::ops::cg::conjugate_gradient;
use diffphys::tape::parallel;
use diffphys_compare::harness::relative_error;
use diffphys_compare::methods::baseline::{baseline_cg, StraightforwardLaplacian};
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::implicit::{cg_params, ImplicitSolve};
use diffphys_compare::methods::naive::NaiveUnrolled;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::problem::{Problem, ProblemSpec};
use ndarray::{ArrayD, IxDyn};

const ITERATION_SIZES: [usize; 5] = [64, 128, 256, 512, 1024];
/// Iterations per timed solve: far from convergence at every size (64² needs
/// about 190 to reach 1e-8), so every iteration does full work.
const ITERATIONS: usize = 20;
const GRADIENT_SIZES: [usize; 2] = [64, 128];
/// The tolerance of the harness's floors.
const GRADIENT_STOP: Stop = Stop::Tolerance {
    rtol: 1e-8,
    max_iters: 20_000,
};

/// `ITERATIONS` fused CG iterations from zero; returns the solution.
fn fused(problem: &Problem<f64>) -> ArrayD<f64> {
    let n = problem.spec.n;
    let mut x = ArrayD::<f64>::zeros(IxDyn(&[n, n]));
    let params = cg_params(Stop::Iterations(ITERATIONS));
    let info = conjugate_gradient(
        &problem.operator,
        problem.b.view().into_dyn(),
        x.view_mut(),
        &params,
    )
    .expect("a fixed-count solve of an SPD system");
    assert_eq!(info.iterations, ITERATIONS);
    x
}

/// `ITERATIONS` straightforward CG iterations from zero; returns the solution.
fn baseline(a: &StraightforwardLaplacian, b: &[f64]) -> Vec<f64> {
    let mut x = vec![0.0; b.len()];
    let info = baseline_cg(a, b, &mut x, Stop::Iterations(ITERATIONS))
        .expect("a fixed-count solve of an SPD system");
    assert_eq!(info.iterations, ITERATIONS);
    x
}

fn iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("cg/iteration");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for n in ITERATION_SIZES {
        let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).expect("scene");
        let a = StraightforwardLaplacian::negative(&problem.grid);
        let b = problem.b.as_standard_layout().into_owned();
        let b = b.as_slice().expect("standard layout");

        // Same matrix, same recurrence: the iterates agree to rounding.
        let (x_fused, x_base) = (fused(&problem), baseline(&a, b));
        let scale = x_base.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = x_fused
            .iter()
            .zip(&x_base)
            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
        assert!(
            diff <= 1e-10 * scale,
            "{n}²: fused and baseline CG differ by {diff:e} (scale {scale:e})"
        );

        group.throughput(Throughput::Elements((n * n * ITERATIONS) as u64));
        group.bench_with_input(BenchmarkId::new("fused", n * n), &n, |bench, _| {
            bench.iter(|| black_box(fused(black_box(&problem))))
        });
        group.bench_with_input(BenchmarkId::new("fused_1_thread", n * n), &n, |bench, _| {
            parallel::with_threads(1, || bench.iter(|| black_box(fused(black_box(&problem)))))
        });
        group.bench_with_input(BenchmarkId::new("baseline", n * n), &n, |bench, _| {
            bench.iter(|| black_box(baseline(&a, black_box(b))))
        });
    }
    group.finish();
}

fn gradient(c: &mut Criterion) {
    let mut group = c.benchmark_group("cg/gradient");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    for n in GRADIENT_SIZES {
        let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).expect("scene");
        let exact = ExactCholesky
            .run(&problem, GRADIENT_STOP)
            .expect("Cholesky of an SPD matrix")
            .gradient;
        let naive = NaiveUnrolled::default();
        let methods: [(&str, &dyn GradientMethod<f64>); 2] =
            [("naive", &naive), ("implicit", &ImplicitSolve)];
        for (name, method) in methods {
            let out = method.run(&problem, GRADIENT_STOP).expect("a gradient");
            let err = relative_error(&out.gradient, &exact).expect("a finite gradient");
            assert!(err < 1e-6, "{n}² {name}: gradient error {err:e} vs exact");
            println!(
                "{n}² {name}: {} CG iterations, tape {} bytes, gradient error vs exact {err:.2e}",
                out.iterations.unwrap_or(0),
                out.tape_bytes
            );
        }

        group.throughput(Throughput::Elements((n * n) as u64));
        for (name, method) in methods {
            group.bench_with_input(BenchmarkId::new(name, n * n), &n, |bench, _| {
                bench.iter(|| {
                    let out = method
                        .run(black_box(&problem), GRADIENT_STOP)
                        .expect("a gradient");
                    black_box(out.gradient)
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, iteration, gradient);
criterion_main!(benches);
