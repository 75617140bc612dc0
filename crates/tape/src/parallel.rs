//! All cores for the large-array kernels, with results that do not depend on the
//! number of threads.
//!
//! Every kernel here splits its arrays into fixed chunks of [`CHUNK`] elements
//! (a length that depends on nothing but the array), runs the chunks on rayon's
//! thread pool when the array has at least [`min_parallel_len`] elements and on
//! the calling thread otherwise, and combines per-chunk partial sums serially in
//! chunk order. So a reduction is bitwise the same on 1, 2 or N threads, and the
//! same whether it ran in parallel or not.
//!
//! The number of threads is rayon's: by default one per core, or the
//! `RAYON_NUM_THREADS` environment variable; [`set_threads`] fixes it for the
//! whole process (before the first parallel kernel runs), and [`with_threads`]
//! runs a closure on a pool of its own.
//!
//! ```
//! use diffphys_tape::parallel;
//!
//! let a: Vec<f64> = (0..100_000).map(|i| (i as f64).sin()).collect();
//! let one = parallel::with_threads(1, || parallel::dot(&a, &a))?;
//! let two = parallel::with_threads(2, || parallel::dot(&a, &a))?;
//! assert_eq!(one.to_bits(), two.to_bits()); // fixed chunking: bitwise equal
//! # Ok::<(), parallel::LengthMismatch>(())
//! ```

use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use crate::Real;

/// Elements per chunk of every chunked kernel and reduction (32 KiB of `f64`:
/// a chunk's partial sum stays in the first-level cache).
pub const CHUNK: usize = 4096;

/// The default of [`min_parallel_len`]: arrays shorter than this run on the
/// calling thread when it is not one of the pool's. Such a call hands its chunks
/// to the pool and sleeps until they are done, and waking the pool costs about
/// 30 µs on the two-core machine of the benchmarks: at 256² (65,536 cells) a CG
/// iteration took 61 µs on one thread and 126 µs on two when its three kernels
/// were each called from outside the pool, while at 1024² two threads halved it
/// (1.66 ms against 3.4 ms). Chunking does not depend on it, so results do not
/// either. On a pool thread the threshold is [`POOL_DISCOUNT`] times lower (see
/// [`is_parallel`]).
pub const PARALLEL_MIN_LEN: usize = 1 << 18;

/// The environment variable that sets [`min_parallel_len`] for a process (a
/// positive integer; anything else is ignored).
pub const MIN_LEN_ENV: &str = "DIFFPHYS_PARALLEL_MIN_LEN";

/// 0 until the first read, which takes [`MIN_LEN_ENV`] or [`PARALLEL_MIN_LEN`].
static MIN_PARALLEL_LEN: AtomicUsize = AtomicUsize::new(0);

/// The length from which kernels split an array across threads:
/// [`set_min_parallel_len`]'s value if it was called, else the
/// `DIFFPHYS_PARALLEL_MIN_LEN` environment variable if it holds a positive
/// integer, else [`PARALLEL_MIN_LEN`].
pub fn min_parallel_len() -> usize {
    let len = MIN_PARALLEL_LEN.load(Ordering::Relaxed);
    if len != 0 {
        return len;
    }
    let from_env = std::env::var(MIN_LEN_ENV)
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(PARALLEL_MIN_LEN);
    // A concurrent set_min_parallel_len wins over the environment.
    match MIN_PARALLEL_LEN.compare_exchange(0, from_env, Ordering::Relaxed, Ordering::Relaxed) {
        Ok(_) => from_env,
        Err(set) => set,
    }
}

/// Sets the length from which kernels split arrays across threads, for the
/// whole process (on a quiet machine smaller arrays may pay). Results do not
/// change: the chunks are the same either way.
pub fn set_min_parallel_len(len: usize) {
    MIN_PARALLEL_LEN.store(len.max(1), Ordering::Relaxed);
}

/// Accumulator lanes of the chunk kernels: independent sums the compiler keeps
/// in vector registers.
const LANES: usize = 4;

/// Sets the number of threads of the process-wide pool that every parallel
/// kernel uses. Call it once, before any parallel kernel has run; `n = 0` means
/// one thread per core.
///
/// # Errors
/// rayon's error if the global pool was already built (by an earlier call or by
/// a kernel that ran before).
pub fn set_threads(n: usize) -> Result<(), rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
}

/// Runs `f` with every parallel kernel inside it on a pool of `n` threads of
/// its own (`n = 0`: one per core), built for this call.
///
/// # Panics
/// If the operating system refuses to start the threads.
pub fn with_threads<R: Send>(n: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .expect("the operating system starts the pool's threads")
        .install(f)
}

/// The number of threads the parallel kernels use here (inside
/// [`with_threads`], that pool's).
pub fn threads() -> usize {
    rayon::current_num_threads()
}

/// Runs `f` on a thread of the pool when it is called from outside the pool
/// and its work, on arrays of `len` elements, would be split there (see
/// [`is_parallel`]).
///
/// A parallel kernel called from a thread that is not one of the pool's hands
/// its chunks to the pool and sleeps until they are done: a few tens of
/// microseconds per call, paid at every synchronisation. A solver that calls
/// kernels thousands of times (CG: three per iteration) runs whole on a worker
/// instead, so that each kernel's split costs a few microseconds. On a pool's
/// thread already (inside [`with_threads`], or nested), or for arrays that
/// stay on one thread, `f` runs here. The result does not depend on where `f`
/// runs: the chunks are the same.
pub fn on_pool<R: Send>(len: usize, f: impl FnOnce() -> R + Send) -> R {
    if len < (min_parallel_len() / POOL_DISCOUNT).max(1) {
        return f();
    }
    to_pool(f)
}

/// Runs `f` on a thread of the pool if it is called from outside the pool
/// and the pool has more than one thread, else here: [`on_pool`] without the
/// size test, for work whose kernels split by rules of their own (the flow
/// step's advection splits from 8,192 entries).
pub fn to_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() || rayon::current_num_threads() <= 1 {
        return f();
    }
    rayon::scope(|_| f())
}

/// How much shorter an array may be on one of the pool's threads than on
/// another thread and still be split: from a pool thread, a split only wakes the
/// other workers (a few µs), with no hand-over to the pool. Measured with CG on
/// `−∇²` on two cores, all kernels called on a pool thread
/// ([`on_pool`]): per iteration 15.3 µs on one thread and 11.5 µs on two at
/// 128², 29.6 and 18.9 µs at 181², 61 and 34 µs at 256²; so from 2¹⁵ cells (the
/// default `2¹⁸ / 8`).
pub const POOL_DISCOUNT: usize = 8;

/// Whether an array of `len` elements is worth splitting across threads: at
/// least [`min_parallel_len`] elements, or `min_parallel_len() / POOL_DISCOUNT`
/// when called on one of the pool's threads, and more than one thread.
pub fn is_parallel(len: usize) -> bool {
    rayon::current_num_threads() > 1 && len >= split_len()
}

/// The length from which an array is split on this thread: [`min_parallel_len`],
/// divided by [`POOL_DISCOUNT`] on one of the pool's threads.
fn split_len() -> usize {
    let min = min_parallel_len();
    if rayon::current_thread_index().is_some() {
        (min / POOL_DISCOUNT).max(1)
    } else {
        min
    }
}

/// Chunks of `chunk_len` per rayon task: enough that an array shorter than the
/// split length of this thread (see [`is_parallel`]) is never split.
fn min_tasks_len(chunk_len: usize) -> usize {
    split_len().div_ceil(chunk_len.max(1)).max(1)
}

/// `f` applied to the ranges `[0, CHUNK)`, `[CHUNK, 2 CHUNK)`, … covering
/// `0..len`, in parallel for large `len`; the results in chunk order.
pub fn map_chunks<R: Send>(len: usize, f: impl Fn(Range<usize>) -> R + Sync + Send) -> Vec<R> {
    map_chunks_by(len, CHUNK, f)
}

/// [`map_chunks`] with chunks of `chunk_len` elements (the last one shorter).
pub fn map_chunks_by<R: Send>(
    len: usize,
    chunk_len: usize,
    f: impl Fn(Range<usize>) -> R + Sync + Send,
) -> Vec<R> {
    let chunk_len = chunk_len.max(1);
    let n_chunks = len.div_ceil(chunk_len);
    let range = |c: usize| c * chunk_len..((c + 1) * chunk_len).min(len);
    if !is_parallel(len) {
        return (0..n_chunks).map(|c| f(range(c))).collect();
    }
    (0..n_chunks)
        .into_par_iter()
        .with_min_len(min_tasks_len(chunk_len))
        .map(|c| f(range(c)))
        .collect()
}

/// `Σ f(chunk)` over the [`CHUNK`]-sized ranges of `0..len`, the partial sums
/// added in chunk order: deterministic whatever the number of threads.
pub fn sum_chunks(len: usize, f: impl Fn(Range<usize>) -> f64 + Sync + Send) -> f64 {
    map_chunks(len, f).into_iter().sum()
}

/// Runs `f(offset, chunk)` on the [`CHUNK`]-sized chunks of `out`, `offset`
/// being the chunk's first index, in parallel for large arrays.
pub fn for_each_chunk_mut<T: Send>(out: &mut [T], f: impl Fn(usize, &mut [T]) + Sync + Send) {
    map_chunks_mut_by(out, CHUNK, |off, o| f(off, o));
}

/// Runs `f(offset, chunk)` on the chunks of `chunk_len` elements of `out` and
/// returns what each returned, in chunk order.
pub fn map_chunks_mut_by<T: Send, R: Send>(
    out: &mut [T],
    chunk_len: usize,
    f: impl Fn(usize, &mut [T]) -> R + Sync + Send,
) -> Vec<R> {
    let chunk_len = chunk_len.max(1);
    if !is_parallel(out.len()) {
        return out
            .chunks_mut(chunk_len)
            .enumerate()
            .map(|(c, o)| f(c * chunk_len, o))
            .collect();
    }
    out.par_chunks_mut(chunk_len)
        .enumerate()
        .with_min_len(min_tasks_len(chunk_len))
        .map(|(c, o)| f(c * chunk_len, o))
        .collect()
}

/// [`map_chunks_mut_by`] with chunks of [`CHUNK`].
pub fn map_chunks_mut<T: Send, R: Send>(
    out: &mut [T],
    f: impl Fn(usize, &mut [T]) -> R + Sync + Send,
) -> Vec<R> {
    map_chunks_mut_by(out, CHUNK, f)
}

/// Runs `f(offset, a_chunk, b_chunk)` on matching [`CHUNK`]-sized chunks of two
/// arrays of the same length, returning what each returned, in chunk order.
///
/// # Errors
/// [`LengthMismatch`] if the lengths differ.
pub fn map_chunks_mut2<T: Send, U: Send, R: Send>(
    a: &mut [T],
    b: &mut [U],
    f: impl Fn(usize, &mut [T], &mut [U]) -> R + Sync + Send,
) -> Result<Vec<R>, LengthMismatch> {
    same_len("parallel::map_chunks_mut2", a.len(), b.len())?;
    if !is_parallel(a.len()) {
        return Ok(a
            .chunks_mut(CHUNK)
            .zip(b.chunks_mut(CHUNK))
            .enumerate()
            .map(|(c, (a, b))| f(c * CHUNK, a, b))
            .collect());
    }
    Ok(a.par_chunks_mut(CHUNK)
        .zip(b.par_chunks_mut(CHUNK))
        .enumerate()
        .with_min_len(min_tasks_len(CHUNK))
        .map(|(c, (a, b))| f(c * CHUNK, a, b))
        .collect())
}

/// Two slices a kernel combines entry by entry have different lengths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{kernel}: the slices have {left} and {right} entries; they must have the same length")]
pub struct LengthMismatch {
    /// The kernel that was called.
    pub kernel: &'static str,
    /// The first slice's length.
    pub left: usize,
    /// The other slice's length.
    pub right: usize,
}

impl From<LengthMismatch> for crate::TapeError {
    fn from(e: LengthMismatch) -> Self {
        crate::TapeError::invalid(e.kernel, e.to_string())
    }
}

fn same_len(kernel: &'static str, left: usize, right: usize) -> Result<(), LengthMismatch> {
    if left == right {
        Ok(())
    } else {
        Err(LengthMismatch {
            kernel,
            left,
            right,
        })
    }
}

#[inline(always)]
fn lanes<T: Copy>(chunk: &[T]) -> &[T; LANES] {
    chunk
        .try_into()
        .expect("chunks_exact yields LANES elements")
}

/// `Σ a_i b_i` of one chunk in `f64`, four lanes then the remainder.
#[inline]
fn dot_chunk_f64<T: Real>(a: &[T], b: &[T]) -> f64 {
    let mut acc = [0.0f64; LANES];
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (a, b) in ac.zip(bc) {
        let (a, b) = (lanes(a), lanes(b));
        for l in 0..LANES {
            acc[l] += wide(a[l]) * wide(b[l]);
        }
    }
    for (a, b) in ar.iter().zip(br) {
        acc[0] += wide(*a) * wide(*b);
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// `Σ a_i b_i` of one chunk in `T`, four lanes then the remainder.
#[inline]
fn dot_chunk<T: Real>(a: &[T], b: &[T]) -> T {
    let mut acc = [T::zero(); LANES];
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (a, b) in ac.zip(bc) {
        let (a, b) = (lanes(a), lanes(b));
        for l in 0..LANES {
            acc[l] += a[l] * b[l];
        }
    }
    for (a, b) in ar.iter().zip(br) {
        acc[0] += *a * *b;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// `Σ a_i` of one chunk in `T`, four lanes then the remainder.
#[inline]
fn sum_chunk<T: Real>(a: &[T]) -> T {
    let mut acc = [T::zero(); LANES];
    let ac = a.chunks_exact(LANES);
    let rest = ac.remainder();
    for a in ac {
        let a = lanes(a);
        for l in 0..LANES {
            acc[l] += a[l];
        }
    }
    for a in rest {
        acc[0] += *a;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// `x` in `f64` (num-traits' conversion, which inlines across crates).
#[inline(always)]
fn wide<T: Real>(x: T) -> f64 {
    x.to_f64().unwrap_or(f64::NAN)
}

/// `Σ a_i b_i` accumulated in `f64` whatever `T`, chunked (deterministic).
///
/// # Errors
/// [`LengthMismatch`] if the lengths differ.
pub fn dot<T: Real>(a: &[T], b: &[T]) -> Result<f64, LengthMismatch> {
    same_len("parallel::dot", a.len(), b.len())?;
    Ok(sum_chunks(a.len(), |r| dot_chunk_f64(&a[r.clone()], &b[r])))
}

/// `Σ a_i b_i` accumulated in `T`, chunked (deterministic): the tape's `dot`.
///
/// # Errors
/// [`LengthMismatch`] if the lengths differ.
pub fn dot_in<T: Real>(a: &[T], b: &[T]) -> Result<T, LengthMismatch> {
    same_len("parallel::dot_in", a.len(), b.len())?;
    Ok(map_chunks(a.len(), |r| dot_chunk(&a[r.clone()], &b[r]))
        .into_iter()
        .fold(T::zero(), |s, p| s + p))
}

/// `Σ a_i` accumulated in `T`, chunked (deterministic): the tape's `sum` and `mean`.
pub fn sum_in<T: Real>(a: &[T]) -> T {
    map_chunks(a.len(), |r| sum_chunk(&a[r]))
        .into_iter()
        .fold(T::zero(), |s, p| s + p)
}

/// `out_i = f(a_i)`, chunked and in parallel for large arrays.
///
/// # Errors
/// [`LengthMismatch`] if the lengths differ.
pub fn map_into<T: Real>(
    a: &[T],
    out: &mut [T],
    f: impl Fn(T) -> T + Sync + Send,
) -> Result<(), LengthMismatch> {
    same_len("parallel::map_into", a.len(), out.len())?;
    for_each_chunk_mut(out, |off, o| {
        let n = o.len();
        for (o, &a) in o.iter_mut().zip(&a[off..off + n]) {
            *o = f(a);
        }
    });
    Ok(())
}

/// `out_i = f(a_i, b_i)`, chunked and in parallel for large arrays.
///
/// # Errors
/// [`LengthMismatch`] if the lengths differ.
pub fn zip_map_into<T: Real>(
    a: &[T],
    b: &[T],
    out: &mut [T],
    f: impl Fn(T, T) -> T + Sync + Send,
) -> Result<(), LengthMismatch> {
    same_len("parallel::zip_map_into", a.len(), out.len())?;
    same_len("parallel::zip_map_into", b.len(), out.len())?;
    for_each_chunk_mut(out, |off, o| {
        let r = off..off + o.len();
        for ((o, &a), &b) in o.iter_mut().zip(&a[r.clone()]).zip(&b[r]) {
            *o = f(a, b);
        }
    });
    Ok(())
}

/// The number of entries of `a` that are NaN or infinite, chunked.
pub fn count_non_finite<T: Real>(a: &[T]) -> usize {
    map_chunks(a.len(), |r| a[r].iter().filter(|v| !v.is_finite()).count())
        .into_iter()
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tests' threshold: low, so that small arrays take the parallel path
    /// (every test sets the same value; results do not depend on it).
    pub(crate) const TEST_MIN_LEN: usize = 2 * CHUNK;

    fn data(n: usize, seed: f64) -> Vec<f64> {
        (0..n).map(|i| ((i as f64) * seed).sin() * 1e3).collect()
    }

    /// The reductions on 1 and 3 threads, and serially below the threshold of
    /// the same chunking, agree bitwise; and agree with plain sums to rounding.
    #[test]
    fn reductions_do_not_depend_on_the_number_of_threads() {
        set_min_parallel_len(TEST_MIN_LEN);
        for n in [0, 5, CHUNK + 3, TEST_MIN_LEN + 17, 10 * CHUNK + 1] {
            let (a, b) = (data(n, 0.37), data(n, 0.11));
            let run = || (dot(&a, &b).unwrap(), dot_in(&a, &b).unwrap(), sum_in(&a));
            let one = with_threads(1, run);
            let three = with_threads(3, run);
            assert_eq!(one.0.to_bits(), three.0.to_bits(), "dot, n = {n}");
            assert_eq!(one.1.to_bits(), three.1.to_bits(), "dot_in, n = {n}");
            assert_eq!(one.2.to_bits(), three.2.to_bits(), "sum_in, n = {n}");
            let plain: f64 = a.iter().zip(&b).map(|(x, y)| x * y).sum();
            let scale: f64 = a.iter().zip(&b).map(|(x, y)| (x * y).abs()).sum();
            assert!((one.0 - plain).abs() <= 1e-13 * scale.max(1.0));
            assert!((one.1 - plain).abs() <= 1e-13 * scale.max(1.0));
            let plain_sum: f64 = a.iter().sum();
            let abs_sum: f64 = a.iter().map(|x| x.abs()).sum();
            assert!((one.2 - plain_sum).abs() <= 1e-13 * abs_sum.max(1.0));
        }
    }

    #[test]
    fn chunk_maps_cover_every_element_once() {
        set_min_parallel_len(TEST_MIN_LEN);
        let n = 3 * TEST_MIN_LEN + 5;
        let a = data(n, 0.2);
        let mut out = vec![0.0; n];
        with_threads(3, || zip_map_into(&a, &a, &mut out, |x, y| x + y)).unwrap();
        assert!(out.iter().zip(&a).all(|(o, a)| *o == 2.0 * a));
        let mut x = vec![1.0; n];
        let mut y = vec![0u8; n];
        let lens = with_threads(2, || {
            map_chunks_mut2(&mut x, &mut y, |off, x, y| {
                x.iter_mut().for_each(|v| *v += off as f64);
                y.fill(1);
                x.len()
            })
        })
        .unwrap();
        assert_eq!(lens.iter().sum::<usize>(), n);
        assert_eq!(x[CHUNK + 1], 1.0 + CHUNK as f64);
        assert!(y.iter().all(|&v| v == 1));
        let mut nan = vec![0.0; n];
        nan[n - 1] = f64::NAN;
        nan[7] = f64::INFINITY;
        assert_eq!(count_non_finite(&nan), 2);
    }

    /// Slices of different lengths are a typed error from every kernel that
    /// combines two, on the serial and the parallel path, never a panic.
    #[test]
    fn mismatched_lengths_are_an_error_not_a_panic() {
        set_min_parallel_len(TEST_MIN_LEN);
        for n in [10, 3 * TEST_MIN_LEN] {
            let (a, b) = (data(n, 0.3), data(n + 1, 0.4));
            let e = dot(&a, &b).unwrap_err();
            assert_eq!((e.kernel, e.left, e.right), ("parallel::dot", n, n + 1));
            assert!(dot_in(&a, &b).is_err());
            let mut out = vec![0.0; n];
            assert!(map_into(&b, &mut out, |v| v).is_err());
            assert!(zip_map_into(&a, &b, &mut out, |x, y| x + y).is_err());
            assert!(zip_map_into(&b, &a, &mut out, |x, y| x + y).is_err());
            let mut c = data(n + 1, 0.5);
            assert!(map_chunks_mut2(&mut out, &mut c, |_, _, _| ()).is_err());
            let te: crate::TapeError = e.into();
            assert!(te.to_string().contains("must have the same length"), "{te}");
        }
    }

    /// A recorded CG-like step (dot, division by a scalar, broadcasting
    /// products, sums, mean) and its gradient, on one thread and on three:
    /// bitwise equal values and gradients.
    #[test]
    fn tape_ops_do_not_depend_on_the_number_of_threads() {
        use crate::{test_array, Tape};
        set_min_parallel_len(TEST_MIN_LEN);
        let n = 3 * TEST_MIN_LEN + 1000;
        let (x0, y0) = (test_array::<f64>(&[n], 1), test_array::<f64>(&[n], 2));
        let run = || {
            let tape = Tape::<f64>::new();
            let (x, y) = (tape.var(x0.clone()), tape.var(y0.clone()));
            let f = || -> crate::Result<_> {
                let alpha = x.dot(y)?.div(y.dot(y)?)?;
                let r = x.sub(y.mul(alpha)?)?;
                let r = r.sub(r.mean()?)?;
                let loss = r.dot(r)?.add(x.mul(y)?.sum()?)?;
                let grads = tape.backward(loss, &[x, y])?;
                Ok((
                    loss.item()?,
                    grads.get(x).unwrap().clone(),
                    grads.get(y).unwrap().clone(),
                ))
            };
            f().unwrap()
        };
        let one = with_threads(1, run);
        let three = with_threads(3, run);
        assert_eq!(one.0.to_bits(), three.0.to_bits());
        let bits = |a: &crate::ArrayD<f64>| a.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&one.1), bits(&three.1));
        assert_eq!(bits(&one.2), bits(&three.2));
    }

    #[test]
    fn with_threads_sets_the_pool_size() {
        assert_eq!(with_threads(3, threads), 3);
        assert!(!with_threads(1, || is_parallel(1 << 20)));
        set_min_parallel_len(TEST_MIN_LEN);
        // On a pool thread (inside with_threads) the threshold is discounted …
        let on_pool_len = TEST_MIN_LEN / POOL_DISCOUNT;
        assert!(with_threads(2, || is_parallel(on_pool_len)));
        assert!(!with_threads(2, || is_parallel(on_pool_len - 1)));
        // … off it (this test's thread) the whole length is needed.
        assert!(!is_parallel(TEST_MIN_LEN - 1));
    }

    #[test]
    fn on_pool_moves_large_work_onto_a_pool_thread() {
        set_min_parallel_len(TEST_MIN_LEN);
        let worker = || rayon::current_thread_index().is_some();
        // Large work from this (non-pool) thread runs on the global pool when it
        // has more than one thread; small work stays here.
        assert_eq!(on_pool(TEST_MIN_LEN, worker), threads() > 1);
        assert!(!on_pool(TEST_MIN_LEN / POOL_DISCOUNT - 1, worker));
        // to_pool moves whatever the size; on a pool thread it stays put.
        assert_eq!(to_pool(worker), threads() > 1);
        assert!(with_threads(2, || to_pool(worker)));
        // On a one-thread pool nothing is split, so nothing moves.
        assert_eq!(with_threads(1, || on_pool(TEST_MIN_LEN, threads)), 1);
        // The result is the same wherever it ran.
        let a: Vec<f64> = (0..3 * CHUNK).map(|i| (i as f64).cos()).collect();
        let here = dot(&a, &a).unwrap();
        let moved = on_pool(TEST_MIN_LEN, || dot(&a, &a).unwrap());
        assert_eq!(here.to_bits(), moved.to_bits());
    }
}
