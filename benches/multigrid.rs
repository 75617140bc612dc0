//! The implicit gradient `∂L/∂b` of `L = ½‖A⁻¹b − p*‖²` (the harness's scene:
//! `A = −∇²`, zero Dirichlet walls, f64) with CG preconditioned by a multigrid
//! V-cycle (MG-PCG, forward and adjoint), against plain CG and the exact
//! sparse-Cholesky gradient, from 256² to 2048².
//!
//! Run: `cargo bench --bench multigrid` (`-- --quick` for a shorter criterion
//! part). Before timing it prints, for every size, the MG-PCG iterations to
//! relative residual 1e-8 (forward + adjoint), the seconds of each gradient
//! (MG-PCG best of 3, the cycle built inside the timing; plain CG and exact
//! one run) and their ratios, and the MG gradient's relative error against
//! exact. Exact runs up to 1024² (its factor at 2048² takes minutes), plain
//! CG up to 512² (about 3000 iterations per solve at 1024²).
//!
//! Then, for the pressure projection with an obstacle (a cylinder, a box;
//! closed walls and an open side), 64² to 1024²: MG-PCG iterations to 1e-8,
//! seconds and microseconds per unknown.
//!
//! `MG_BENCH_SIZES=256,1024` picks the sizes of the first report, `MG_SWEEPS=1`
//! the smoothing sweeps of the cycle (default 2).

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use diffphys::ops::cg::CgParams;
use diffphys::ops::multigrid::Multigrid;
use diffphys::ops::poisson::PoissonSolve;
use diffphys::prelude::*;
use diffphys_compare::harness::relative_error;
use diffphys_compare::methods::exact::ExactCholesky;
use diffphys_compare::methods::{GradientMethod, Stop};
use diffphys_compare::problem::{Problem, ProblemSpec};
use ndarray::Array2;

const SIZES: [usize; 4] = [256, 512, 1024, 2048];
const EXACT_UP_TO: usize = 1024;
/// Plain CG takes ~3000 iterations per solve at 1024²: reported up to here.
const PLAIN_UP_TO: usize = 512;
const RTOL: f64 = 1e-8;
const SWEEPS: usize = 2;

/// The gradient through the Poisson op with `params`, and its CG iterations.
fn implicit_gradient(problem: &Problem<f64>, params: CgParams) -> (Array2<f64>, usize, usize) {
    let solve = PoissonSolve::new(Arc::new(problem.operator.clone()), params);
    let log = solve.log();
    let tape = Tape::<f64>::new();
    let b = tape.var(problem.b.clone().into_dyn());
    let p = tape.apply(solve, &[b]).expect("the solve converges");
    let d = p
        .sub(tape.constant(problem.target.clone().into_dyn()))
        .expect("shapes");
    let loss = d
        .mul(d)
        .and_then(|l| l.sum())
        .and_then(|l| l.mul_scalar(0.5))
        .expect("loss");
    let g = tape.backward(loss, &[b]).expect("backward");
    let g = g
        .get(b)
        .expect("gradient")
        .clone()
        .into_dimensionality()
        .expect("2-D");
    let (f, a) = (
        log.last_forward().expect("a solve"),
        log.last_adjoint().expect("a solve"),
    );
    (g, f.iterations, a.iterations)
}

fn mg_params(problem: &Problem<f64>) -> CgParams {
    let mg = Multigrid::new(&problem.grid, sweeps()).expect("the grid coarsens");
    CgParams::default()
        .with_rel_tol(RTOL)
        .with_preconditioner(Arc::new(mg))
}

fn best_of_3(mut f: impl FnMut()) -> f64 {
    (0..3)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The sizes of the report: [`SIZES`], or those listed in `MG_BENCH_SIZES`
/// (comma-separated, e.g. `MG_BENCH_SIZES=1024`).
fn sizes() -> Vec<usize> {
    std::env::var("MG_BENCH_SIZES")
        .ok()
        .map(|s| s.split(',').filter_map(|v| v.trim().parse().ok()).collect())
        .unwrap_or_else(|| SIZES.to_vec())
}

/// Smoothing sweeps per half-cycle: `MG_SWEEPS`, default [`SWEEPS`].
fn sweeps() -> usize {
    std::env::var("MG_SWEEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(SWEEPS)
}

fn report() {
    println!("n      MG-PCG its   MG-PCG s   plain CG its   plain CG s   exact s   exact/MG   plain/MG   MG err vs exact");
    for n in sizes() {
        let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).expect("scene");
        let (g_mg, f_mg, a_mg) = implicit_gradient(&problem, mg_params(&problem));
        let t_mg = best_of_3(|| {
            black_box(implicit_gradient(&problem, mg_params(&problem)));
        });
        let plain = CgParams::default()
            .with_rel_tol(RTOL)
            .with_max_iters(20_000);
        let (f_cg, a_cg, t_cg) = if n <= PLAIN_UP_TO {
            let start = Instant::now();
            let (_, f, a) = implicit_gradient(&problem, plain.clone());
            (
                f.to_string(),
                a.to_string(),
                Some(start.elapsed().as_secs_f64()),
            )
        } else {
            ("-".to_string(), "-".to_string(), None)
        };
        let (t_exact, err) = if n <= EXACT_UP_TO {
            let exact = ExactCholesky
                .run(&problem, Stop::Iterations(0))
                .expect("exact");
            let start = Instant::now();
            black_box(
                ExactCholesky
                    .run(&problem, Stop::Iterations(0))
                    .expect("exact"),
            );
            let t = start.elapsed().as_secs_f64();
            let g_exact = exact.gradient.mapv(|v| v);
            (Some(t), relative_error(&g_mg, &g_exact))
        } else {
            (None, None)
        };
        let fmt = |v: Option<f64>, p: usize| v.map_or("-".to_string(), |v| format!("{v:.p$}"));
        println!(
            "{n:<6} {:>5}+{:<5} {t_mg:>9.4} {:>7}+{:<6} {:>10} {:>9} {:>10} {:>10} {:>14}",
            f_mg,
            a_mg,
            f_cg,
            a_cg,
            fmt(t_cg, 4),
            fmt(t_exact, 4),
            fmt(t_exact.map(|t| t / t_mg), 2),
            fmt(t_cg.map(|t| t / t_mg), 1),
            err.map_or("-".to_string(), |e| format!("{e:.2e}")),
        );
    }
}

/// MG-PCG on the pressure operator of a staggered grid with an obstacle (a
/// cylinder and a box; closed walls, and an open side): iterations to relative
/// residual 1e-8 from 64² to 1024², the solve's best-of-3 seconds (the cycle
/// built inside the timing) and microseconds per unknown.
fn obstacle_report() {
    use diffphys::ops::mac::MacGrid;
    use diffphys::ops::projection::PressureProjection;
    use diffphys::ops::Boundary::{Closed, ZeroDirichlet};
    use diffphys::ops::CellMask;
    let cylinder = |c: [f64; 2]| (c[0] - 0.4).powi(2) + (c[1] - 0.5).powi(2) > 0.15f64.powi(2);
    let boxed = |c: [f64; 2]| !((0.3..0.6).contains(&c[0]) && (0.35..0.55).contains(&c[1]));
    println!("\nMG-PCG with obstacles (pressure projection, rtol 1e-8)");
    println!("n      sides    obstacle   its    seconds   us/unknown");
    for n in [64, 128, 256, 512, 1024] {
        for (sides, bx) in [("closed", Closed), ("open", ZeroDirichlet)] {
            let grid = Grid2::new(n, n, 1.0 / n as f64, 1.0 / n as f64, Closed)
                .expect("grid")
                .with_boundaries(bx, Closed);
            for (shape, fluid) in [
                ("cylinder", &cylinder as &dyn Fn([f64; 2]) -> bool),
                ("box", &boxed),
            ] {
                let mac = MacGrid::with_mask(grid, CellMask::from_fn2(&grid, fluid)).expect("mask");
                let ux = Array2::from_shape_fn(mac.shape_x(), |(i, j)| {
                    ((i * 7 + j * 3) % 11) as f64 - 5.0
                });
                let uy = Array2::from_shape_fn(mac.shape_y(), |(i, j)| {
                    ((i * 5 + j * 13) % 7) as f64 - 3.0
                });
                let solve = || {
                    let proj = PressureProjection::new(
                        mac.clone(),
                        CgParams::default().with_rel_tol(RTOL),
                    )
                    .with_multigrid(sweeps())
                    .expect("the grid coarsens");
                    proj.project(ux.view().into_dyn(), uy.view().into_dyn(), None)
                        .expect("the solve converges")
                };
                let its = solve().info.iterations;
                let t = best_of_3(|| {
                    black_box(solve());
                });
                println!(
                    "{n:<6} {sides:<8} {shape:<9} {its:>4} {t:>10.4} {:>12.3}",
                    t * 1e6 / (n * n) as f64
                );
            }
        }
    }
}

fn bench(c: &mut Criterion) {
    report();
    obstacle_report();
    let n = 256;
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n)).expect("scene");
    let mut group = c.benchmark_group("multigrid/gradient");
    group.throughput(Throughput::Elements((n * n) as u64));
    group.sample_size(10);
    group.bench_function("mg_pcg_256", |b| {
        b.iter(|| black_box(implicit_gradient(&problem, mg_params(&problem))))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
