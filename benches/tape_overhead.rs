//! Tape overhead: a chain of eight elementwise ops recorded on the tape against the
//! same maths written as plain ndarray expressions (one pass and one allocation per
//! op in both), forward only and forward + backward, from 1e2 to 1e6 elements.
//!
//! The chain, with constants `a`, `b`:
//!
//! ```text
//! u = a·x + b,  h = tanh u,  p = h·x,  q = p²,  r = −½ q,  e = exp r,  y = e + x,
//! L = Σ y
//! ∂L/∂x = 1 − e·p·(h + x·(1 − h²)·a)
//! ```
//!
//! Run: `cargo bench --bench tape_overhead` (`-- --quick` for a short run). Reports
//! read as elements per second; the ratio tape / plain at each size is the overhead.
//!
//! From about 1e5 elements (800 kB arrays) glibc serves each array with a fresh
//! `mmap` and returns it on drop, so page faults dominate both sides, the tape's
//! more (it holds every intermediate until it is dropped). Running with
//! `GLIBC_TUNABLES=glibc.malloc.mmap_threshold=33554432:glibc.malloc.trim_threshold=1073741824`
//! keeps freed memory in the process and shows the arithmetic-bound ratio.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use diffphys::prelude::*;

const SIZES: [usize; 5] = [100, 1_000, 10_000, 100_000, 1_000_000];

/// The chain on the tape, from `x` to `y` (eight recorded ops).
fn chain_tape<'t>(
    x: Var<'t, f64>,
    a: Var<'t, f64>,
    b: Var<'t, f64>,
) -> Result<Var<'t, f64>, TapeError> {
    let u = x.mul(a)?.add(b)?;
    let h = u.tanh()?;
    let p = h.mul(x)?;
    let q = p.mul(p)?;
    let e = q.mul_scalar(-0.5)?.exp()?;
    e.add(x)
}

/// The intermediates the plain backward needs.
struct Plain {
    h: ArrayD<f64>,
    p: ArrayD<f64>,
    e: ArrayD<f64>,
    y: ArrayD<f64>,
}

/// The chain as plain ndarray expressions, one pass per op as on the tape.
fn chain_plain(x: &ArrayD<f64>, a: &ArrayD<f64>, b: &ArrayD<f64>) -> Plain {
    let u = x * a + b;
    let h = u.mapv(f64::tanh);
    let p = &h * x;
    let q = &p * &p;
    let e = (q * -0.5).mapv(f64::exp);
    let y = &e + x;
    Plain { h, p, e, y }
}

/// `∂L/∂x` of `L = Σ y`, by hand, op by op in reverse.
fn grad_plain(x: &ArrayD<f64>, a: &ArrayD<f64>, f: &Plain) -> ArrayD<f64> {
    let g_p = -(&f.e * &f.p); // ∂L/∂p = e · (−p)
    let g_h = &g_p * x;
    let g_u = g_h * &f.h.mapv(|h| 1.0 - h * h);
    let mut g_x = g_p * &f.h + g_u * a;
    g_x += 1.0; // y = e + x
    g_x
}

fn inputs(n: usize) -> [ArrayD<f64>; 3] {
    [
        test_array(&[n], 1),
        test_array(&[n], 2),
        test_array(&[n], 3),
    ]
}

fn forward(c: &mut Criterion) {
    let mut group = c.benchmark_group("tape_overhead/forward");
    for n in SIZES {
        let [x, a, b] = inputs(n);
        group.throughput(Throughput::Elements(n as u64));
        if n >= 100_000 {
            group.sample_size(20);
        }
        group.bench_with_input(BenchmarkId::new("tape", n), &n, |bench, _| {
            bench.iter(|| {
                let tape = Tape::new();
                let xv = tape.var(black_box(&x).clone());
                let av = tape.constant(black_box(&a).clone());
                let bv = tape.constant(black_box(&b).clone());
                let y = chain_tape(xv, av, bv).expect("finite chain");
                let first = y.value()[[0]];
                black_box(first)
            })
        });
        group.bench_with_input(BenchmarkId::new("ndarray", n), &n, |bench, _| {
            bench.iter(|| black_box(chain_plain(black_box(&x), black_box(&a), black_box(&b)).y))
        });
    }
    group.finish();
}

fn forward_backward(c: &mut Criterion) {
    let mut group = c.benchmark_group("tape_overhead/forward_backward");
    for n in SIZES {
        let [x, a, b] = inputs(n);
        group.throughput(Throughput::Elements(n as u64));
        if n >= 100_000 {
            group.sample_size(20);
        }
        group.bench_with_input(BenchmarkId::new("tape", n), &n, |bench, _| {
            bench.iter(|| {
                let tape = Tape::new();
                let xv = tape.var(black_box(&x).clone());
                let av = tape.constant(black_box(&a).clone());
                let bv = tape.constant(black_box(&b).clone());
                let loss = chain_tape(xv, av, bv)
                    .and_then(|y| y.sum())
                    .expect("finite chain");
                let mut grads = tape.backward(loss, &[xv]).expect("finite gradient");
                black_box(grads.take(xv))
            })
        });
        group.bench_with_input(BenchmarkId::new("ndarray", n), &n, |bench, _| {
            bench.iter(|| {
                let (x, a, b) = (black_box(&x), black_box(&a), black_box(&b));
                let f = chain_plain(x, a, b);
                black_box(f.y.sum());
                black_box(grad_plain(x, a, &f))
            })
        });
    }
    group.finish();
}

/// Checks once, before timing, that the hand-written gradient is the tape's.
fn same_gradient(_: &mut Criterion) {
    let [x, a, b] = inputs(257);
    let tape = Tape::new();
    let xv = tape.var(x.clone());
    let loss = chain_tape(xv, tape.constant(a.clone()), tape.constant(b.clone()))
        .and_then(|y| y.sum())
        .expect("finite chain");
    let grads = tape.backward(loss, &[xv]).expect("finite gradient");
    let plain = grad_plain(&x, &a, &chain_plain(&x, &a, &b));
    let diff = (grads.get(xv).expect("requested") - &plain)
        .iter()
        .fold(0.0f64, |m, d| m.max(d.abs()));
    assert!(diff < 1e-14, "tape and plain gradients differ by {diff:e}");
}

criterion_group!(benches, same_gradient, forward, forward_backward);
criterion_main!(benches);
