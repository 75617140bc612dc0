//! The flow step (diffphys-flow), forward and forward + backward per step, on
//! the scenes the peers are measured on (benches/flow_peers): the wake flow
//! with its cylinder at 32 x 64, 128 x 256 and 512 x 1024, and the periodic
//! Taylor–Green box at 64², 128² and 256², f32 like the peers' runs.
//!
//! Forward: one `Scene::forward` (no tape) from the scene's start state.
//! Forward + backward: one `Scene::step` on a fresh tape and the gradient of
//! `½|u|²` after it with respect to the start velocity (the implicit pressure
//! adjoint). Throughput is cells per second.
//!
//! `flow_maccormack_periodic`: the MacCormack velocity advection alone (with
//! the limiter) on the periodic Taylor–Green box at 128² and 512², f32
//! fields: `advect_velocity` (forward), and it followed by
//! `advect_velocity_vjp` (forward + backward, as a tape's step runs them).
//!
//! Run: `cargo bench --bench flow` (`-- --quick` for a shorter run;
//! `RAYON_NUM_THREADS=1` for the one-core figures of the peers' table).
//! `FLOW_BENCH_LARGE=0` leaves out 512 x 1024.

#[path = "../examples/flow_common/mod.rs"]
mod flow_common;

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::flow::advection::{advect_velocity, advect_velocity_vjp};
use diffphys::flow::{Advection, Faces, FlowGrid, FlowState, FlowVars, ParamVars, Scene, Sides};
use diffphys::tape::{Real, Tape};
use ndarray::{Array1, Array2};

fn forward<T: Real>(scene: &Scene, start: &FlowState<T>) -> FlowState<T> {
    scene
        .forward(start, &scene.params())
        .expect("the step runs")
        .0
}

fn forward_backward<T: Real>(scene: &Scene, start: &FlowState<T>) -> T {
    let tape = Tape::<T>::new();
    let v0 = FlowVars::variables(&tape, start);
    let p = ParamVars::constants(&tape, &scene.params());
    let (v, _) = scene.step(&tape, &v0, &p).expect("the step runs");
    let loss =
        v.ux.dot(v.ux)
            .and_then(|a| a.add(v.uy.dot(v.uy)?))
            .and_then(|l| l.mul_scalar(T::from_f64(0.5)))
            .expect("the loss");
    let g = tape.backward(loss, &[v0.ux, v0.uy]).expect("backward");
    g.get(v0.ux).expect("a gradient")[[0, 0]]
}

fn bench_scene<T: Real>(
    c: &mut Criterion,
    group: &str,
    label: &str,
    scene: &Scene,
    start: &FlowState<T>,
) {
    let cells = (scene.grid().nx * scene.grid().ny) as u64;
    let mut g = c.benchmark_group(group);
    g.throughput(Throughput::Elements(cells));
    if cells > 100_000 {
        g.sample_size(10).measurement_time(Duration::from_secs(20));
    }
    g.bench_function(BenchmarkId::new("forward", label), |b| {
        b.iter(|| forward(black_box(scene), black_box(start)))
    });
    g.bench_function(BenchmarkId::new("forward_backward", label), |b| {
        b.iter(|| forward_backward(black_box(scene), black_box(start)))
    });
    g.finish();
}

fn wake(c: &mut Criterion) {
    let large = std::env::var("FLOW_BENCH_LARGE").map_or(true, |v| v != "0");
    for res in [32, 128, 512] {
        if res == 512 && !large {
            continue;
        }
        let scene = flow_common::wake_scene(res, None).expect("the wake scene builds");
        let start = flow_common::wake_start::<f32>(&scene).expect("the wake starts");
        bench_scene(
            c,
            "flow_wake_f32",
            &format!("{res}x{}", 2 * res),
            &scene,
            &start,
        );
    }
}

fn periodic_box(c: &mut Criterion) {
    for n in [64, 128, 256] {
        let (scene, start) = flow_common::box_scene::<f32>(n, None).expect("the box builds");
        bench_scene(c, "flow_box_f32", &format!("{n}x{n}"), &scene, &start);
    }
    let (scene, start) = flow_common::box_scene::<f64>(128, None).expect("the box builds");
    bench_scene(c, "flow_box_f64", "128x128", &scene, &start);
}

/// The MacCormack step of the velocity on a periodic `n × n` box of side
/// 2π: the Taylor–Green field plus a perturbation, dt at Courant number ½.
fn maccormack_periodic(c: &mut Criterion) {
    let mut g = c.benchmark_group("flow_maccormack_periodic_f32");
    for n in [128, 512] {
        let h = 2.0 * std::f64::consts::PI / n as f64;
        let grid = FlowGrid {
            nx: n,
            ny: n,
            dx: h,
            dy: h,
            sides: Sides::periodic(),
        };
        let faces = Faces::classify(&grid, &Array2::from_elem((n, n), false));
        let scheme = Advection::MacCormack { limiter: true };
        let dt = 0.5 * h;
        let wobble = |a: usize, b: usize| 0.3 * (((a * 7 + b * 13) % 17) as f64 / 17.0 - 0.5);
        let ux = Array2::from_shape_fn(grid.shape_x(), |(a, b)| {
            let (x, y) = (a as f64 * h, (b as f64 + 0.5) * h);
            (x.sin() * y.cos() + wobble(a, b)) as f32
        });
        let uy = Array2::from_shape_fn(grid.shape_y(), |(a, b)| {
            let (x, y) = ((a as f64 + 0.5) * h, b as f64 * h);
            (-x.cos() * y.sin() + wobble(b, a)) as f32
        });
        let walls = Array1::<f32>::zeros(4);
        let run = || {
            advect_velocity(
                &grid,
                &faces,
                scheme,
                dt,
                (ux.view(), uy.view()),
                (ux.view(), uy.view()),
                walls.view(),
            )
            .expect("the advection runs")
        };
        g.throughput(Throughput::Elements((n * n) as u64));
        if n > 256 {
            g.sample_size(20);
        }
        g.bench_function(BenchmarkId::new("forward", n), |b| {
            b.iter(|| black_box(run()))
        });
        g.bench_function(BenchmarkId::new("forward_backward", n), |b| {
            b.iter(|| {
                let (ax, ay) = run();
                advect_velocity_vjp(
                    &grid,
                    &faces,
                    scheme,
                    dt,
                    (ux.view(), uy.view()),
                    (ux.view(), uy.view()),
                    walls.view(),
                    (ax.view(), ay.view()),
                )
                .expect("the product runs")
            })
        });
    }
    g.finish();
}

criterion_group!(benches, wake, periodic_box, maccormack_periodic);
criterion_main!(benches);
