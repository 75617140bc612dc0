//! The machine's streaming bandwidth, the denominator of the flow step's
//! roofline (docs/08, "Sixth round: the step's roofline"): a stream copy `b = a` and a
//! stream triad `c = a + s b` over f64 arrays sized to sit in L2, in L3 and in
//! main memory, on one thread and split over two.
//!
//! Throughput is the bytes the kernel must move (copy: read `a`, write `b`;
//! triad: read `a` and `b`, write `c`), not counting the write-allocate read a
//! cache makes of `b` or `c` before it overwrites them, so the figure is what
//! an operator's byte count (reads plus writes) divides by.
//!
//! Run: `cargo bench --bench bandwidth` (`-- --quick` for a shorter run).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

/// Working sets, in bytes over all arrays of the triad: inside a 1 MiB L2,
/// inside a 32 MiB L3, and well past it.
const SETS: [(&str, usize); 3] = [
    ("l2_768KiB", 768 << 10),
    ("l3_12MiB", 12 << 20),
    ("dram_384MiB", 384 << 20),
];

/// Passes over a working set per timed call: enough that the threads' start
/// (tens of microseconds) is a small part of a call on the in-cache sets.
fn passes(bytes: usize) -> usize {
    (64 << 20) / bytes + 1
}

/// `b = a`, `reps` times, split into `threads` contiguous blocks, each block
/// on its own thread for all the passes (so an in-cache block stays in its
/// core's cache).
fn copy(a: &[f64], b: &mut [f64], threads: usize, reps: usize) {
    let block = a.len().div_ceil(threads);
    std::thread::scope(|s| {
        for (a, b) in a.chunks(block).zip(b.chunks_mut(block)) {
            s.spawn(move || {
                for _ in 0..reps {
                    b.copy_from_slice(black_box(a));
                }
            });
        }
    });
}

/// `c = a + s b`, split and repeated as [`copy`].
fn triad(a: &[f64], b: &[f64], c: &mut [f64], s: f64, threads: usize, reps: usize) {
    let block = a.len().div_ceil(threads);
    std::thread::scope(|scope| {
        let blocks = a.chunks(block).zip(b.chunks(block));
        for ((a, b), c) in blocks.zip(c.chunks_mut(block)) {
            scope.spawn(move || {
                for _ in 0..reps {
                    for ((c, a), b) in c.iter_mut().zip(black_box(a)).zip(b) {
                        *c = a + s * b;
                    }
                }
            });
        }
    });
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("bandwidth");
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    for (label, bytes) in SETS {
        // Three arrays of the triad share the working set; the copy uses two.
        let n = bytes / (3 * std::mem::size_of::<f64>());
        let a: Vec<f64> = (0..n).map(|i| i as f64).collect();
        let b: Vec<f64> = (0..n).map(|i| (n - i) as f64).collect();
        let mut out = vec![0.0f64; n];
        for threads in [1usize, 2] {
            let reps = passes(bytes);
            let moved = |arrays: usize| (reps * arrays * n * std::mem::size_of::<f64>()) as u64;
            group.throughput(Throughput::Bytes(moved(2)));
            group.bench_with_input(
                BenchmarkId::new(format!("copy_{threads}t"), label),
                &threads,
                |bencher, &t| bencher.iter(|| copy(black_box(&a), black_box(&mut out), t, reps)),
            );
            group.throughput(Throughput::Bytes(moved(3)));
            group.bench_with_input(
                BenchmarkId::new(format!("triad_{threads}t"), label),
                &threads,
                |bencher, &t| {
                    bencher.iter(|| {
                        triad(
                            black_box(&a),
                            black_box(&b),
                            black_box(&mut out),
                            0.5,
                            t,
                            reps,
                        )
                    })
                },
            );
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
