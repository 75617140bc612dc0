//! The step's kernels' buffers and loops: fields in `f64` (borrowed where
//! they already are), outputs and scratch from the current buffer pool, and
//! the split of per-row and per-component work across cores.
//!
//! **Buffers.** A tape records a step's fields by the thousand, and its
//! reverse sweep makes as many gradients; fresh from the allocator each
//! is memory the operating system faults in page by page (at 256² a
//! 100-step vector–Jacobian product faulted in about 600 MB a call, a third
//! of its time). The kernels take their outputs and scratch from the pool
//! current on their thread ([`diffphys_tape::pool`]: the tape's while it
//! runs an op, or one the caller installs) and give scratch back, so a caller
//! that keeps one pool across calls (a training loop, the Python `FlowStep`)
//! reuses them; with no pool current they come from the allocator as before.
//! [`join`] installs the caller's pool on the second thread too.

use std::ops::Deref;

use diffphys_tape::pool::{self, BufferPool};
use diffphys_tape::{parallel, PerPrecision, Real};
use ndarray::{Array2, ArrayView1, ArrayView2};
use rayon::prelude::*;

/// `n` zeros, from the current pool if it holds a buffer of that length.
pub(crate) fn zeros(n: usize) -> Vec<f64> {
    pool::take_filled(n, 0.0)
}

/// `n` pairs of zeros, from the current pool if it holds such a buffer.
pub(crate) fn zero_pairs(n: usize) -> Vec<[f64; 2]> {
    pool::take_filled(n, [0.0; 2])
}

/// `n` entries to be overwritten, every one: from the current pool (stale
/// contents) or zeros.
pub(crate) fn scratch(n: usize) -> Vec<f64> {
    pool::take(n)
}

/// Gives a scratch buffer back to the current pool (or the allocator).
pub(crate) fn give_back<V: Copy + Send + 'static>(v: Vec<V>) {
    pool::recycle(v)
}

/// `(a(), b())` on two threads ([`rayon::join`]), each with the caller's
/// current pool installed.
pub(crate) fn join<RA: Send, RB: Send>(
    a: impl FnOnce() -> RA + Send,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    let pool = BufferPool::current();
    let pool = &pool;
    rayon::join(|| within(pool, a), || within(pool, b))
}

/// `f()` with `pool` installed, if any.
fn within<R>(pool: &Option<BufferPool>, f: impl FnOnce() -> R) -> R {
    match pool {
        Some(p) => p.scope(f),
        None => f(),
    }
}

/// Runs `f(offset, block)` on blocks of whole rows of `row` entries of `out`
/// (about [`parallel::CHUNK`] entries each, at least one row), on all cores
/// where [`parallel::is_parallel`] says an array of its length splits: the
/// step's per-row loops (stencils, the Fourier solve's transforms), whose rows
/// are computed alone, so the same bits on any number of threads. (Splitting
/// them from [`crate::advection::PARALLEL_FROM`] entries, as the advection does, was slower at
/// 128² on two cores: the wake-ups cost more than the halved rows.)
pub(crate) fn for_row_blocks<V: Send>(
    out: &mut [V],
    row: usize,
    f: impl Fn(usize, &mut [V]) + Sync + Send,
) {
    if row > 0 {
        let len = parallel::CHUNK.div_ceil(row) * row;
        in_blocks(out, len, parallel::is_parallel(out.len()), f);
    }
}

/// Runs `f(offset, block)` on the blocks of `len` entries of `out`, on all
/// cores where `split`.
pub(crate) fn in_blocks<V: Send>(
    out: &mut [V],
    len: usize,
    split: bool,
    f: impl Fn(usize, &mut [V]) + Sync + Send,
) {
    if split {
        out.par_chunks_mut(len)
            .enumerate()
            .for_each(|(c, o)| f(c * len, o));
    } else {
        out.chunks_mut(len)
            .enumerate()
            .for_each(|(c, o)| f(c * len, o));
    }
}

/// Runs `f(offset, a_block, b_block)` on the blocks of `len` entries of `a`
/// and the same entries of `b` (as long as `a`), on all cores where `split`.
pub(crate) fn in_block_pairs<A: Send, B: Send>(
    a: &mut [A],
    b: &mut [B],
    len: usize,
    split: bool,
    f: impl Fn(usize, &mut [A], &mut [B]) + Sync + Send,
) {
    if split {
        a.par_chunks_mut(len)
            .zip(b.par_chunks_mut(len))
            .enumerate()
            .for_each(|(c, (x, y))| f(c * len, x, y));
    } else {
        a.chunks_mut(len)
            .zip(b.chunks_mut(len))
            .enumerate()
            .for_each(|(c, (x, y))| f(c * len, x, y));
    }
}

/// `f64` values of a slice: the slice itself in `f64`, none in `f32`.
struct AsWide;
impl PerPrecision for AsWide {
    type Of<T: Real> = for<'b> fn(&'b [T]) -> Option<&'b [f64]>;
}

/// Values from `f64`: the vector itself in `f64`, converted in `f32`.
struct FromWide;
impl PerPrecision for FromWide {
    type Of<T: Real> = fn(Vec<f64>) -> Vec<T>;
}

/// An array's entries in `f64`, row-major ([`wide`]): borrowed from an
/// `f64` array, or converted into a buffer from the current pool that goes
/// back to it when dropped (the step widens its `f32` fields several times
/// a step; from the allocator, every large one was pages faulted in anew).
pub(crate) enum Wide<'a> {
    /// The array's own `f64` entries.
    Borrowed(&'a [f64]),
    /// The entries converted, in a pool buffer.
    Pooled(Vec<f64>),
}

impl Deref for Wide<'_> {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        match self {
            Wide::Borrowed(s) => s,
            Wide::Pooled(v) => v,
        }
    }
}

impl Drop for Wide<'_> {
    fn drop(&mut self) {
        if let Wide::Pooled(v) = self {
            give_back(std::mem::take(v));
        }
    }
}

impl Wide<'_> {
    /// The entries as a vector of their own: the converted buffer itself,
    /// or a copy of the borrowed entries in a buffer from the current pool.
    pub(crate) fn into_owned(mut self) -> Vec<f64> {
        match &mut self {
            Wide::Pooled(v) => std::mem::take(v),
            Wide::Borrowed(s) => copied(s),
        }
    }
}

/// The entries of `a` in `f64`, row-major: borrowed when `a` is a
/// standard-layout `f64` array, converted (into a pool buffer) otherwise.
pub(crate) fn wide<T: Real>(a: ArrayView2<'_, T>) -> Wide<'_> {
    let borrow = T::pick::<AsWide>(|_| None, |s| Some(s));
    match a.to_slice() {
        Some(s) => match borrow(s) {
            Some(s) => Wide::Borrowed(s),
            None => {
                let mut v = scratch(s.len());
                // one vectorised pass
                v.iter_mut().zip(s).for_each(|(o, x)| *o = x.as_f64());
                Wide::Pooled(v)
            }
        },
        None => {
            let mut v = scratch(a.len());
            v.iter_mut()
                .zip(a.iter())
                .for_each(|(o, x)| *o = x.as_f64());
            Wide::Pooled(v)
        }
    }
}

/// `v` as an array of `T` of `shape` (moved, not copied, in `f64`).
pub(crate) fn narrow<T: Real>(shape: [usize; 2], v: Vec<f64>) -> Array2<T> {
    let convert = T::pick::<FromWide>(
        |v| {
            let mut out: Vec<f32> = pool::take(v.len());
            out.iter_mut().zip(&v).for_each(|(o, &x)| *o = x as f32);
            give_back(v);
            out
        },
        |v| v,
    );
    crate::boundaries::array2(shape, convert(v))
}

/// The four wall speeds in `f64`.
pub(crate) fn walls_of<T: Real>(w: ArrayView1<'_, T>) -> [f64; 4] {
    [w[0].as_f64(), w[1].as_f64(), w[2].as_f64(), w[3].as_f64()]
}

/// The values of `c` as a vector of their own: moved if converted, else
/// copied into a buffer from the current pool.
pub(crate) fn owned(c: Wide<'_>) -> Vec<f64> {
    c.into_owned()
}

/// A copy of `s` in a buffer from the current pool.
pub(crate) fn copied(s: &[f64]) -> Vec<f64> {
    let mut v = scratch(s.len());
    v.copy_from_slice(s);
    v
}
