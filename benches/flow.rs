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
//! Run: `cargo bench --bench flow` (`-- --quick` for a shorter run;
//! `RAYON_NUM_THREADS=1` for the one-core figures of the peers' table).
//! `FLOW_BENCH_LARGE=0` leaves out 512 x 1024.

#[path = "../examples/flow_common/mod.rs"]
mod flow_common;

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::flow::{FlowState, FlowVars, ParamVars, Scene};
use diffphys::tape::{Real, Tape};

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

criterion_group!(benches, wake, periodic_box);
criterion_main!(benches);
