//! The convolution's forward + backward as the fused op (a register-blocked
//! direct kernel, one node, adjoint by hand) against the same convolution built
//! from tape primitives (per kernel tap: roll, broadcast multiply, sum over
//! input channels, add), and the fused op computing in f32 on the same f64 tape
//! (`Arithmetic::Single`), with periodic padding and gradients in the input, the
//! kernel and the bias, in two cases: 2D at batch 8, 16 → 16 channels, 3×3
//! kernel, 64² cells (the wake flow's corrector), and 1D at batch 16, 32 → 32
//! channels, kernel 5, 128 cells (the widest layer of the Burgers scenes'
//! U-Net, whose weight gradient was once 9× slower than it is).
//!
//! A second group times the forward pass alone at batch 1 (a corrector
//! inside a rollout), 16 → 16 channels, 3×3, in f32 arithmetic on the f64
//! tape, at 32×64 and 64×64 cells: on one thread and split over all cores.
//!
//! Run: `cargo bench --bench nn_conv` (`-- --quick` for a short run). Before
//! timing it prints, for each variant, the tape's peak bytes, the best of five
//! forward + backward times, their ratios, and the largest gradient difference
//! to the fused op in f64.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use diffphys::nn::conv::conv_forward;
use diffphys::nn::reference::conv_from_primitives;
use diffphys::nn::{Arithmetic, ConvOp, Padding};
use diffphys::prelude::*;

/// One convolution: its name and the shapes of its input and kernel.
struct Case {
    name: &'static str,
    x: &'static [usize],
    w: &'static [usize],
}

const CASES: [Case; 2] = [
    Case {
        name: "conv2d batch 8, 16→16, 3×3, 64²",
        x: &[8, 16, 64, 64],
        w: &[16, 16, 3, 3],
    },
    Case {
        name: "conv1d batch 16, 32→32, kernel 5, 128",
        x: &[16, 32, 128],
        w: &[32, 32, 5],
    },
];

#[derive(Clone, Copy, Debug)]
enum Variant {
    /// The fused op in f64.
    Op,
    /// The fused op computing in f32 on the f64 tape ([`Arithmetic::Single`]).
    OpSingle,
    Primitives,
}

struct Inputs {
    x: ArrayD<f64>,
    w: ArrayD<f64>,
    b: ArrayD<f64>,
    seed: ArrayD<f64>,
}

fn inputs(case: &Case) -> Inputs {
    let mut y = case.x.to_vec();
    y[1] = case.w[0];
    Inputs {
        x: test_array(case.x, 1),
        w: test_array(case.w, 2),
        b: test_array(&[case.w[0]], 3),
        seed: test_array(&y, 4),
    }
}

/// Forward and backward once; the three gradients and the tape's statistics.
fn run(variant: Variant, inp: &Inputs) -> ([ArrayD<f64>; 3], TapeStats) {
    let tape = Tape::<f64>::new();
    let (x, w, b) = (
        tape.var(inp.x.clone()),
        tape.var(inp.w.clone()),
        tape.var(inp.b.clone()),
    );
    let y = match variant {
        Variant::Op | Variant::OpSingle => tape.apply(
            ConvOp {
                name: "conv".into(),
                padding: Padding::Periodic,
                arithmetic: if matches!(variant, Variant::Op) {
                    Arithmetic::Native
                } else {
                    Arithmetic::Single
                },
                threads: 1,
            },
            &[x, w, b],
        ),
        Variant::Primitives => conv_from_primitives(x, w, b, Padding::Periodic),
    }
    .expect("the convolution records");
    let grads = tape
        .backward_with_seed(y, inp.seed.clone(), &[x, w, b])
        .expect("backward");
    let g = [x, w, b].map(|v| grads.get(v).expect("a gradient").clone());
    (g, tape.stats())
}

fn best_seconds(variant: Variant, inp: &Inputs) -> f64 {
    (0..5)
        .map(|_| {
            let start = Instant::now();
            black_box(run(variant, inp));
            start.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn report(case: &Case, inp: &Inputs) {
    let (g_op, s_op) = run(Variant::Op, inp);
    let (g_single, _) = run(Variant::OpSingle, inp);
    let (g_prim, s_prim) = run(Variant::Primitives, inp);
    let largest_difference = |g: &[ArrayD<f64>; 3]| {
        g_op.iter()
            .zip(g)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(p, q)| (p - q).abs()))
            .fold(0.0, f64::max)
    };
    let (diff, diff_single) = (largest_difference(&g_prim), largest_difference(&g_single));
    let (t_op, t_single, t_prim) = (
        best_seconds(Variant::Op, inp),
        best_seconds(Variant::OpSingle, inp),
        best_seconds(Variant::Primitives, inp),
    );
    println!(
        "{}: op {:.2} ms, {} B, {} nodes; \
         primitives {:.2} ms, {} B, {} nodes; primitives/op time {:.1}, bytes {:.1}; \
         max |grad difference| {diff:.1e}; op in f32 {:.2} ms ({:.2}× faster than f64), \
         max |grad difference| to f64 {diff_single:.1e}",
        case.name,
        t_op * 1e3,
        s_op.peak_bytes,
        s_op.nodes,
        t_prim * 1e3,
        s_prim.peak_bytes,
        s_prim.nodes,
        t_prim / t_op,
        s_prim.peak_bytes as f64 / s_op.peak_bytes as f64,
        t_single * 1e3,
        t_op / t_single,
    );
}

fn bench(c: &mut Criterion) {
    for (case, group_name) in CASES
        .iter()
        .zip(["conv2d_forward_backward", "conv1d_forward_backward"])
    {
        let inp = inputs(case);
        report(case, &inp);
        let mut group = c.benchmark_group(group_name);
        group.throughput(Throughput::Elements(inp.x.len() as u64));
        group.sample_size(10);
        for variant in [Variant::Op, Variant::OpSingle, Variant::Primitives] {
            group.bench_function(format!("{variant:?}").to_lowercase(), |bench| {
                bench.iter(|| black_box(run(variant, &inp)))
            });
        }
        group.finish();
    }
}

/// The forward pass alone at batch 1, 16 → 16 channels, 3×3, f32 arithmetic,
/// zero padding: one thread against all cores.
fn bench_threads(c: &mut Criterion) {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    let w = test_array::<f64>(&[16, 16, 3, 3], 2);
    let b = test_array::<f64>(&[16], 3);
    let mut group = c.benchmark_group("conv2d_forward_batch1_threads");
    group.sample_size(20);
    for (h, wd) in [(32, 64), (64, 64)] {
        let x = test_array::<f64>(&[1, 16, h, wd], 1);
        group.throughput(Throughput::Elements((h * wd) as u64));
        for threads in std::iter::once(1).chain((cores > 1).then_some(cores)) {
            let name = format!("{h}x{wd}/{threads}_threads");
            group.bench_function(name, |bench| {
                bench.iter(|| {
                    black_box(conv_forward(
                        "conv",
                        x.view(),
                        w.view(),
                        b.view(),
                        Padding::Zero,
                        Arithmetic::Single,
                        threads,
                    ))
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench, bench_threads);
criterion_main!(benches);
