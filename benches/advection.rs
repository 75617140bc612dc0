//! One upwind advection step on the tape, as the monolithic op (one node, adjoint
//! by hand) against the same scheme in tape primitives (twelve nodes in 1D,
//! twenty-odd in 2D), forward + backward with gradients in the field and the
//! velocity, periodic boundaries, 1D and 2D at several sizes.
//!
//! Run: `cargo bench --bench advection` (`-- --quick` for a short run). Reports
//! read as cells per second. Before timing, each size prints the tape bytes of
//! both variants (`TapeStats::peak_bytes`) and their ratio, and checks that the
//! two gradients agree.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::ops::advection::{AdvectionParams, Upwind1, Upwind2};
use diffphys::prelude::*;

type StepResult<'t> = diffphys::tape::Result<Var<'t, f64>>;

const SIZES_1D: [usize; 3] = [1_000, 10_000, 100_000];
const SIZES_2D: [usize; 3] = [32, 128, 512];

/// The 1D step in primitives (periodic neighbours by `roll`).
fn upwind_1d_primitives<'t>(
    grid: &Grid1,
    dt: f64,
    d: Var<'t, f64>,
    u: Var<'t, f64>,
) -> StepResult<'t> {
    let zero = d.tape().scalar(0.0);
    let c = u.mul_scalar(1.0 / grid.dx)?;
    let (u_plus, u_minus) = (zero.minimum(c)?, zero.maximum(c)?);
    let forward = d.roll(-1, 0)?.sub(d)?;
    let backward = d.sub(d.roll(1, 0)?)?;
    let rate = u_plus.mul(forward)?.add(u_minus.mul(backward)?)?;
    d.sub(rate.mul_scalar(dt)?)
}

/// The 2D step in primitives, per axis, with `u` of shape `[2, nx, ny]`.
fn upwind_2d_primitives<'t>(
    grid: &Grid2,
    dt: f64,
    d: Var<'t, f64>,
    u: Var<'t, f64>,
) -> StepResult<'t> {
    let shape = [grid.nx, grid.ny];
    let zero = d.tape().scalar(0.0);
    let mut out = d;
    for (axis, h) in [(0, grid.dx), (1, grid.dy)] {
        let c = u
            .slice(0, axis, axis + 1)?
            .reshape(&shape)?
            .mul_scalar(1.0 / h)?;
        let (u_plus, u_minus) = (zero.minimum(c)?, zero.maximum(c)?);
        let forward = d.roll(-1, axis)?.sub(d)?;
        let backward = d.sub(d.roll(1, axis)?)?;
        let rate = u_plus.mul(forward)?.add(u_minus.mul(backward)?)?;
        out = out.sub(rate.mul_scalar(dt)?)?;
    }
    Ok(out)
}

/// The two ways to record a step.
#[derive(Clone, Copy)]
enum Variant {
    Op,
    Primitives,
}

/// A grid and step that can be recorded either way.
trait Scheme {
    fn step<'t>(&self, variant: Variant, d: Var<'t, f64>, u: Var<'t, f64>) -> StepResult<'t>;
}

struct OneD {
    grid: Grid1,
    params: AdvectionParams,
}

impl Scheme for OneD {
    fn step<'t>(&self, variant: Variant, d: Var<'t, f64>, u: Var<'t, f64>) -> StepResult<'t> {
        match variant {
            Variant::Op => Ok(d
                .tape()
                .apply(Upwind1::new(self.grid, self.params), &[d, u])?),
            Variant::Primitives => upwind_1d_primitives(&self.grid, self.params.dt, d, u),
        }
    }
}

struct TwoD {
    grid: Grid2,
    params: AdvectionParams,
}

impl Scheme for TwoD {
    fn step<'t>(&self, variant: Variant, d: Var<'t, f64>, u: Var<'t, f64>) -> StepResult<'t> {
        match variant {
            Variant::Op => Ok(d
                .tape()
                .apply(Upwind2::new(self.grid, self.params), &[d, u])?),
            Variant::Primitives => upwind_2d_primitives(&self.grid, self.params.dt, d, u),
        }
    }
}

/// What one recorded step gave: the gradients in `d` and `u`, and the tape's size.
struct Recorded {
    grad_d: ArrayD<f64>,
    grad_u: ArrayD<f64>,
    stats: TapeStats,
}

/// One step from `(d, u)` on a fresh tape, loss `<w, d'>`, gradients in both.
fn step_and_gradients(
    scheme: &impl Scheme,
    variant: Variant,
    d: &ArrayD<f64>,
    u: &ArrayD<f64>,
    w: &ArrayD<f64>,
) -> Recorded {
    let tape = Tape::new();
    let (dv, uv) = (tape.var(d.clone()), tape.var(u.clone()));
    let loss = scheme
        .step(variant, dv, uv)
        .and_then(|out| out.dot(tape.constant(w.clone())))
        .expect("a stable step");
    let mut grads = tape.backward(loss, &[dv, uv]).expect("finite gradients");
    Recorded {
        grad_d: grads.take(dv).expect("requested"),
        grad_u: grads.take(uv).expect("requested"),
        stats: tape.stats(),
    }
}

fn max_diff(a: &ArrayD<f64>, b: &ArrayD<f64>) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()))
}

/// Prints the tape bytes of both variants and checks their gradients agree.
fn report(label: &str, scheme: &impl Scheme, d: &ArrayD<f64>, u: &ArrayD<f64>, w: &ArrayD<f64>) {
    let op = step_and_gradients(scheme, Variant::Op, d, u, w);
    let prim = step_and_gradients(scheme, Variant::Primitives, d, u, w);
    let diff = max_diff(&op.grad_d, &prim.grad_d).max(max_diff(&op.grad_u, &prim.grad_u));
    assert!(
        diff < 1e-10,
        "{label}: op and primitive gradients differ by {diff:e}"
    );
    println!(
        "{label}: tape bytes op {} ({} nodes), primitives {} ({} nodes), ratio {:.2}; max |Δgrad| {diff:.1e}",
        op.stats.peak_bytes,
        op.stats.nodes,
        prim.stats.peak_bytes,
        prim.stats.nodes,
        prim.stats.peak_bytes as f64 / op.stats.peak_bytes as f64
    );
}

/// Times both variants of `scheme` at one size.
fn bench_both(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    size: usize,
    scheme: &impl Scheme,
    inputs: &(ArrayD<f64>, ArrayD<f64>, ArrayD<f64>),
) {
    let (d, u, w) = inputs;
    for (name, variant) in [("op", Variant::Op), ("primitives", Variant::Primitives)] {
        group.bench_with_input(BenchmarkId::new(name, size), &size, |b, _| {
            b.iter(|| black_box(step_and_gradients(scheme, variant, black_box(d), u, w)))
        });
    }
}

/// A velocity with Courant number at most `0.8·c_max` in either direction.
fn velocity(shape: &[usize], scale: f64) -> ArrayD<f64> {
    test_array::<f64>(shape, 2).mapv(|v| 0.8 * scale * v)
}

fn one_d(c: &mut Criterion) {
    let mut group = c.benchmark_group("advection/upwind_1d_step");
    for n in SIZES_1D {
        let scheme = OneD {
            grid: Grid1::new(n, 1.0 / n as f64, 0.0, Boundary::Periodic).expect("grid"),
            params: AdvectionParams::new(0.5 / n as f64), // Courant ≤ 0.5·max|u|
        };
        let inputs = (
            test_array(&[n], 1),
            velocity(&[n], 1.0),
            test_array(&[n], 3),
        );
        report(
            &format!("1D n = {n}"),
            &scheme,
            &inputs.0,
            &inputs.1,
            &inputs.2,
        );
        group.throughput(Throughput::Elements(n as u64));
        if n >= 100_000 {
            group.sample_size(20);
        }
        bench_both(&mut group, n, &scheme, &inputs);
    }
    group.finish();
}

fn two_d(c: &mut Criterion) {
    let mut group = c.benchmark_group("advection/upwind_2d_step");
    for n in SIZES_2D {
        let h = 1.0 / n as f64;
        let scheme = TwoD {
            grid: Grid2::square(n, n, h, Boundary::Periodic).expect("grid"),
            params: AdvectionParams::new(0.25 * h), // Courant ≤ 0.5·max|u|
        };
        let inputs = (
            test_array(&[n, n], 1),
            velocity(&[2, n, n], 1.0),
            test_array(&[n, n], 3),
        );
        report(
            &format!("2D {n}×{n}"),
            &scheme,
            &inputs.0,
            &inputs.1,
            &inputs.2,
        );
        group.throughput(Throughput::Elements((n * n) as u64));
        if n >= 512 {
            group.sample_size(20);
        }
        bench_both(&mut group, n * n, &scheme, &inputs);
    }
    group.finish();
}

criterion_group!(benches, one_d, two_d);
criterion_main!(benches);
