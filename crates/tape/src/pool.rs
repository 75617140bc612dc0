//! Buffer pools: array buffers reused by type and length, owned by whoever
//! made them.
//!
//! A tape that unrolls an iterative solver records arrays of a handful of
//! lengths, thousands of times, and its reverse sweep consumes as many
//! gradients. Without reuse each is fresh memory the operating system faults in
//! page by page. A [`BufferPool`] keeps the buffers that are let go (a consumed
//! gradient, the values of a dropped tape) and hands them to the next op asking
//! for one of the same type and length.
//!
//! **Ownership.** There is no global pool. Every [`crate::Tape`] holds one:
//! its own, made by [`crate::Tape::new`] and freed with the tape, or one the
//! caller passes ([`crate::Tape::with_pool`]) or installs for a scope
//! ([`BufferPool::install`], [`BufferPool::scope`]): a training loop that makes a
//! new tape per step keeps one pool alive across steps, and that pool's memory
//! is returned to the allocator when the caller drops its last handle.
//!
//! **Bounds.** A pool keeps a buffer only for a length that is asked for: of
//! each type and length it holds at most as many buffers as [`take`] has
//! ever had out at once (its *demand*), so buffers of lengths only ever
//! recycled (an op's output made without [`take`], a shape of the first
//! iteration only) go back to the allocator, and a loop that records the same
//! shapes every step holds what one step needs. On top of that, each pool
//! holds at most its limit ([`DEFAULT_LIMIT_BYTES`] unless set).
//!
//! While a tape runs an op's forward or backward (and while it drops its
//! values), its pool is the thread's *current* pool: [`take`] and [`recycle`],
//! which ops call, use it. Outside any tape (and with no pool installed) they
//! fall back to the allocator.
//!
//! ```
//! use diffphys_tape::pool::{self, BufferPool};
//!
//! let pool = BufferPool::new();
//! {
//!     let _current = pool.install();
//!     let v: Vec<f64> = pool::take(10_000); // fresh: zeros
//!     pool::recycle(v);
//! }
//! assert_eq!(pool.held_bytes(), 80_000);
//! pool.scope(|| {
//!     let w: Vec<f64> = pool::take(10_000); // the same buffer, contents unspecified
//!     assert_eq!(w.len(), 10_000);
//! });
//! assert_eq!(pool.held_bytes(), 0);
//! // With no pool current, buffers come from and go back to the allocator.
//! pool::recycle(vec![0.0f64; 10_000]);
//! assert_eq!(pool.held_bytes(), 0);
//! drop(pool); // what it held goes back to the allocator
//! ```

use std::any::{Any, TypeId};
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use ndarray::{ArrayD, IxDyn};

use crate::Real;

/// Buffers shorter than this are left to the allocator, which serves small
/// sizes from memory it already holds.
pub const MIN_POOLED_LEN: usize = 1024;

/// The most bytes a pool keeps unless told otherwise: 512 MiB.
pub const DEFAULT_LIMIT_BYTES: usize = 512 << 20;

/// The buffers of one type and length, and their demand.
#[derive(Default)]
struct Slot {
    buffers: Vec<Box<dyn Any + Send>>,
    /// Buffers [`take`] handed out and not yet recycled (an estimate: a
    /// recycled buffer that did not come from `take` counts it down too).
    out: usize,
    /// The most that were out at once: the most this slot keeps.
    demand: usize,
}

#[derive(Default)]
struct Free {
    slots: HashMap<(TypeId, usize), Slot>,
    bytes: usize,
}

struct Shared {
    free: Mutex<Free>,
    limit: AtomicUsize,
}

/// A pool of array buffers, keyed by element type and length. A handle:
/// clones share one pool, whose buffers go back to the allocator when the last
/// handle is dropped. `Send` and `Sync`: one job may hand its pool to the
/// threads it splits onto (each installs it, [`BufferPool::scope`]), and an
/// object that runs jobs on a thread pool (a solver called from Python) may
/// own one across calls.
#[derive(Clone)]
pub struct BufferPool {
    shared: Arc<Shared>,
}

impl Default for BufferPool {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for BufferPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BufferPool")
            .field("held_bytes", &self.held_bytes())
            .field("limit_bytes", &self.limit_bytes())
            .finish()
    }
}

thread_local! {
    /// The pools made current by [`BufferPool::install`], innermost last.
    static CURRENT: RefCell<Vec<BufferPool>> = const { RefCell::new(Vec::new()) };
}

/// Makes a pool current until dropped (see [`BufferPool::install`]).
#[must_use = "the pool is current only while the guard lives"]
pub struct Installed {
    // Not Send: the guard must be dropped on the thread that installed it.
    _not_send: std::marker::PhantomData<*const ()>,
}

impl Drop for Installed {
    fn drop(&mut self) {
        // Take the handle out first: dropping it may free buffers, which must
        // not happen under the borrow.
        let popped = CURRENT.with(|c| c.borrow_mut().pop());
        drop(popped);
    }
}

impl BufferPool {
    /// An empty pool holding at most [`DEFAULT_LIMIT_BYTES`].
    pub fn new() -> Self {
        Self::with_limit_bytes(DEFAULT_LIMIT_BYTES)
    }

    /// An empty pool holding at most `bytes` (0: nothing is kept).
    pub fn with_limit_bytes(bytes: usize) -> Self {
        BufferPool {
            shared: Arc::new(Shared {
                free: Mutex::new(Free::default()),
                limit: AtomicUsize::new(bytes),
            }),
        }
    }

    /// The pool that is current on this thread (the innermost installed, or
    /// the pool of the tape running an op), if any.
    pub fn current() -> Option<BufferPool> {
        CURRENT.with(|c| c.borrow().last().cloned())
    }

    /// Makes this pool the thread's current one until the guard is dropped:
    /// [`take`] and [`recycle`] use it, and a [`crate::Tape::new`] made meanwhile
    /// shares it instead of making its own. Installs nest.
    pub fn install(&self) -> Installed {
        CURRENT.with(|c| c.borrow_mut().push(self.clone()));
        Installed {
            _not_send: std::marker::PhantomData,
        }
    }

    /// Runs `f` with this pool installed (see [`BufferPool::install`]).
    pub fn scope<R>(&self, f: impl FnOnce() -> R) -> R {
        let _current = self.install();
        f()
    }

    /// The most bytes this pool keeps.
    pub fn limit_bytes(&self) -> usize {
        self.shared.limit.load(Ordering::Relaxed)
    }

    /// Sets the most bytes this pool keeps; buffers beyond it go back to the
    /// allocator as they are recycled ([`BufferPool::clear`] empties the pool
    /// now).
    pub fn set_limit_bytes(&self, bytes: usize) {
        self.shared.limit.store(bytes, Ordering::Relaxed);
    }

    /// Bytes this pool holds now.
    pub fn held_bytes(&self) -> usize {
        self.free().bytes
    }

    /// The free lists, locked (a panic elsewhere while they were held left
    /// them consistent: every update is a push or a pop and a count).
    fn free(&self) -> MutexGuard<'_, Free> {
        self.shared.free.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Returns every buffer this pool holds to the allocator.
    pub fn clear(&self) {
        let buffers = {
            let mut free = self.free();
            free.bytes = 0;
            free.slots
                .values_mut()
                .map(|slot| std::mem::take(&mut slot.buffers))
                .collect::<Vec<_>>()
        };
        drop(buffers);
    }

    /// Whether `other` is a handle to the same pool.
    pub fn same_as(&self, other: &BufferPool) -> bool {
        Arc::ptr_eq(&self.shared, &other.shared)
    }

    /// Whether this is the only handle to the pool (so what it would keep is
    /// freed with it).
    pub(crate) fn is_unshared(&self) -> bool {
        Arc::strong_count(&self.shared) == 1
    }

    /// A held buffer of `len` elements, if any; counts the request towards
    /// the length's demand either way (the caller allocates on `None`).
    fn take<T: Copy + Send + 'static>(&self, len: usize) -> Option<Vec<T>> {
        let v = {
            let mut free = self.free();
            let slot = free.slots.entry((TypeId::of::<T>(), len)).or_default();
            slot.out += 1;
            slot.demand = slot.demand.max(slot.out);
            let v = slot.buffers.pop()?;
            free.bytes -= len * std::mem::size_of::<T>();
            v
        };
        v.downcast::<Vec<T>>().ok().map(|v| *v)
    }

    /// Keeps `buffer` (full-length, long enough) or gives it back: if its
    /// length already has as many buffers held as its demand, or the pool is
    /// at its limit.
    fn keep<T: Copy + Send + 'static>(&self, buffer: Vec<T>) -> Option<Vec<T>> {
        let len = buffer.len();
        let bytes = len * std::mem::size_of::<T>();
        let limit = self.limit_bytes();
        let mut free = self.free();
        let held = free.bytes;
        let Some(slot) = free.slots.get_mut(&(TypeId::of::<T>(), len)) else {
            return Some(buffer);
        };
        slot.out = slot.out.saturating_sub(1);
        if slot.buffers.len() >= slot.demand || held + bytes > limit {
            return Some(buffer);
        }
        slot.buffers.push(Box::new(buffer));
        free.bytes += bytes;
        None
    }
}

/// A buffer of `len` elements: a recycled one from the current pool (contents
/// unspecified: callers overwrite every element) or, if it has none of that
/// length or no pool is current, zeros.
pub fn take<T: Real>(len: usize) -> Vec<T> {
    take_or(len, T::zero())
}

/// [`take`] for any plain element type (a complex number, a pair): a
/// recycled buffer of `len` elements (contents unspecified) or, if the
/// current pool has none, `len` copies of `fresh`.
pub fn take_or<T: Copy + Send + 'static>(len: usize, fresh: T) -> Vec<T> {
    recycled(len).unwrap_or_else(|| vec![fresh; len])
}

/// A buffer of `len` copies of `value`: a recycled one filled, or a fresh
/// one (written once either way).
pub fn take_filled<T: Copy + Send + 'static>(len: usize, value: T) -> Vec<T> {
    match recycled(len) {
        Some(mut v) => {
            v.fill(value);
            v
        }
        None => vec![value; len],
    }
}

/// A buffer of `len` elements from the current pool, if it holds one (and
/// the length is pooled at all).
fn recycled<T: Copy + Send + 'static>(len: usize) -> Option<Vec<T>> {
    if len < MIN_POOLED_LEN {
        return None;
    }
    BufferPool::current().and_then(|p| p.take(len))
}

/// Gives `buffer` to the current pool for a later [`take`] of its length
/// (dropped instead if it is short, if the pool is full or if no pool is
/// current).
pub fn recycle<T: Copy + Send + 'static>(buffer: Vec<T>) {
    if buffer.len() < MIN_POOLED_LEN || buffer.capacity() != buffer.len() {
        return;
    }
    if let Some(pool) = BufferPool::current() {
        let rejected = pool.keep(buffer);
        drop(rejected);
    }
}

/// An array of `shape` in standard layout from [`take`] (contents unspecified).
pub fn take_array<T: Real>(shape: &[usize]) -> ArrayD<T> {
    let len = shape.iter().product();
    ArrayD::from_shape_vec(IxDyn(shape), take(len)).expect("the length is the shape's product")
}

/// [`take_array`] filled with zeros, for kernels that accumulate into their
/// output.
pub fn take_zeroed_array<T: Real>(shape: &[usize]) -> ArrayD<T> {
    let mut a = take_array::<T>(shape);
    let s = a.as_slice_mut().expect("pooled arrays are contiguous");
    crate::parallel::for_each_chunk_mut(s, |_, o| o.fill(T::zero()));
    a
}

/// Gives the buffer of `a` to the current pool (see [`recycle`]) if `a` owns
/// all of it in standard layout.
pub fn recycle_array<T: Real>(a: ArrayD<T>) {
    if !a.is_standard_layout() {
        return;
    }
    let (v, offset) = a.into_raw_vec_and_offset();
    if offset.unwrap_or(0) == 0 {
        recycle(v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffers_are_reused_by_type_and_length_within_the_limit() {
        let pool = BufferPool::new();
        let _current = pool.install();
        let v: Vec<f64> = take(4096);
        assert!(v.iter().all(|&x| x == 0.0));
        let ptr = v.as_ptr();
        recycle(v);
        assert_eq!(pool.held_bytes(), 4096 * 8);
        // Another type or length does not get it.
        let w: Vec<f32> = take(4096);
        let u: Vec<f64> = take(4097);
        assert_eq!(pool.held_bytes(), 4096 * 8);
        let v: Vec<f64> = take(4096);
        assert_eq!((v.as_ptr(), pool.held_bytes()), (ptr, 0));
        // Short buffers and those beyond the limit go back to the allocator.
        recycle(vec![1.0f64; 10]);
        assert_eq!(pool.held_bytes(), 0);
        pool.set_limit_bytes(4096 * 8);
        recycle(v);
        recycle(u);
        assert_eq!(pool.held_bytes(), 4096 * 8);
        pool.set_limit_bytes(DEFAULT_LIMIT_BYTES);
        let a: ArrayD<f32> = take_array(&[64, 64]);
        recycle_array(a);
        assert_eq!(pool.held_bytes(), 4096 * 8 + 4096 * 4);
        drop(w);
        pool.clear();
        assert_eq!(pool.held_bytes(), 0);
    }

    #[test]
    fn a_pool_keeps_a_length_only_up_to_its_demand() {
        let pool = BufferPool::new();
        let _current = pool.install();
        // A length nobody asked for is not kept.
        recycle(vec![0.0f64; 2048]);
        assert_eq!(pool.held_bytes(), 0);
        // Three out at once: the demand is three.
        let taken: Vec<Vec<f64>> = (0..3).map(|_| take(2048)).collect();
        for v in taken {
            recycle(v);
        }
        assert_eq!(pool.held_bytes(), 3 * 2048 * 8);
        // More of that length recycled than were ever out: not kept.
        recycle(vec![0.0f64; 2048]);
        assert_eq!(pool.held_bytes(), 3 * 2048 * 8);
        // The held buffers serve the next three requests; a fourth is fresh
        // and raises the demand.
        let again: Vec<Vec<f64>> = (0..4).map(|_| take(2048)).collect();
        assert_eq!(pool.held_bytes(), 0);
        for v in again {
            recycle(v);
        }
        assert_eq!(pool.held_bytes(), 4 * 2048 * 8);
    }

    #[test]
    fn a_pool_serves_the_threads_a_job_splits_onto() {
        let pool = BufferPool::new();
        std::thread::scope(|s| {
            for _ in 0..2 {
                s.spawn(|| {
                    pool.scope(|| {
                        let v: Vec<f64> = take(4096);
                        recycle(v);
                    })
                });
            }
        });
        // each thread's buffer came back to the one pool (one or two held:
        // the demand depends on whether the two were out at once)
        let held = pool.held_bytes();
        assert!((4096 * 8..=2 * 4096 * 8).contains(&held), "held {held}");
        let reused = pool.scope(|| take::<f64>(4096));
        assert_eq!(pool.held_bytes(), held - 4096 * 8);
        drop(reused);
    }

    #[test]
    fn installs_nest_and_end_with_their_guard() {
        let (outer, inner) = (BufferPool::new(), BufferPool::new());
        assert!(BufferPool::current().is_none());
        let g = outer.install();
        inner.scope(|| {
            assert!(BufferPool::current().unwrap().same_as(&inner));
            recycle(take::<f32>(2048));
        });
        assert!(BufferPool::current().unwrap().same_as(&outer));
        recycle(take::<f32>(4096));
        drop(g);
        assert!(BufferPool::current().is_none());
        assert_eq!((inner.held_bytes(), outer.held_bytes()), (8192, 16384));
    }
}
