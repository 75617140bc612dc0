//! A per-thread pool of array buffers, keyed by element type and length.
//!
//! A tape that unrolls an iterative solver records arrays of a handful of
//! lengths, thousands of times. Without reuse, every one of them is fresh memory
//! that the operating system must fault in page by page (and, for large arrays,
//! unmap again when the tape is dropped). With the pool, the buffers of a
//! dropped tape ([`crate::Tape`] returns its values here), and the gradients the
//! reverse sweep consumes, are handed to the next op that needs one of the same
//! length: a repeated run and the backward pass touch memory that is already
//! mapped.
//!
//! The pool holds at most [`limit_bytes`] (4 GiB unless [`set_limit_bytes`]
//! says otherwise); [`clear`] returns everything to the allocator, which a
//! caller measuring the peak heap of a cold run should do first, since buffers
//! taken from the pool are not new allocations.
//!
//! ```
//! use diffphys_tape::pool;
//!
//! let v: Vec<f64> = pool::take(10_000); // fresh: zeros
//! pool::recycle(v);
//! assert_eq!(pool::held_bytes(), 80_000);
//! let w: Vec<f64> = pool::take(10_000); // the same buffer, contents unspecified
//! assert_eq!((w.len(), pool::held_bytes()), (10_000, 0));
//! ```

use std::any::{Any, TypeId};
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};

use ndarray::{ArrayD, IxDyn};

use crate::Real;

/// Buffers shorter than this are left to the allocator, which serves small
/// sizes from memory it already holds.
pub const MIN_POOLED_LEN: usize = 1024;

static LIMIT_BYTES: AtomicUsize = AtomicUsize::new(4 << 30);

#[derive(Default)]
struct Pool {
    free: HashMap<(TypeId, usize), Vec<Box<dyn Any>>>,
    bytes: usize,
}

thread_local! {
    static POOL: RefCell<Pool> = RefCell::new(Pool::default());
}

/// The most bytes the pool of one thread keeps.
pub fn limit_bytes() -> usize {
    LIMIT_BYTES.load(Ordering::Relaxed)
}

/// Sets the most bytes the pool of each thread keeps (0 turns reuse across
/// tapes off); buffers beyond it go back to the allocator. Takes effect as
/// buffers are recycled; [`clear`] empties the pool now.
pub fn set_limit_bytes(bytes: usize) {
    LIMIT_BYTES.store(bytes, Ordering::Relaxed);
}

/// Bytes this thread's pool holds now.
pub fn held_bytes() -> usize {
    POOL.with(|p| p.borrow().bytes)
}

/// Returns every buffer of this thread's pool to the allocator.
pub fn clear() {
    // Take the map out first: dropping buffers must not run under the borrow.
    let free = POOL.with(|p| {
        let mut p = p.borrow_mut();
        p.bytes = 0;
        std::mem::take(&mut p.free)
    });
    drop(free);
}

/// A buffer of `len` elements: a recycled one (contents unspecified: callers
/// overwrite every element) or, if the pool has none of that length, zeros.
pub fn take<T: Real>(len: usize) -> Vec<T> {
    if len >= MIN_POOLED_LEN {
        let found = POOL.with(|p| {
            let mut p = p.borrow_mut();
            let v = p.free.get_mut(&(TypeId::of::<T>(), len))?.pop()?;
            p.bytes -= len * std::mem::size_of::<T>();
            Some(v)
        });
        if let Some(v) = found {
            if let Ok(v) = v.downcast::<Vec<T>>() {
                return *v;
            }
        }
    }
    vec![T::zero(); len]
}

/// Gives `buffer` to this thread's pool for a later [`take`] of its length
/// (dropped instead if it is short or the pool is full).
pub fn recycle<T: Real>(buffer: Vec<T>) {
    let len = buffer.len();
    let bytes = len * std::mem::size_of::<T>();
    if len < MIN_POOLED_LEN || buffer.capacity() != len {
        return;
    }
    let rejected = POOL.with(|p| {
        let mut p = p.borrow_mut();
        if p.bytes + bytes > limit_bytes() {
            return Some(buffer);
        }
        p.bytes += bytes;
        p.free
            .entry((TypeId::of::<T>(), len))
            .or_default()
            .push(Box::new(buffer));
        None
    });
    drop(rejected);
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

/// Gives the buffer of `a` to the pool (see [`recycle`]) if `a` owns all of it
/// in standard layout.
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

    /// The values of a dropped tape serve the next tape's ops of the same length.
    #[test]
    fn a_dropped_tape_gives_its_values_to_the_next() {
        use crate::{test_array, Tape};
        clear();
        let x0 = test_array::<f64>(&[5000], 3);
        let record = || {
            let tape = Tape::<f64>::new();
            let x = tape.var(x0.clone());
            let y = x.mul(x).unwrap().add(x).unwrap();
            let g = tape.backward(y.sum().unwrap(), &[x]).unwrap();
            // d/dx Σ (x² + x) = 2x + 1
            let expect = x0.mapv(|v| 2.0 * v + 1.0);
            assert!(g
                .get(x)
                .unwrap()
                .iter()
                .zip(&expect)
                .all(|(a, b)| (a - b).abs() < 1e-12));
        };
        record();
        let held = held_bytes();
        // x, x², x² + x and the gradients the sweep consumed.
        assert!(held >= 3 * 5000 * 8, "{held}");
        record();
        // Without reuse the second tape would add its x², x² + x and gradients
        // again; with it, at most its own leaf is new.
        let again = held_bytes();
        assert!(again <= held + 5000 * 8, "{held} then {again}");
        clear();
    }

    #[test]
    fn buffers_are_reused_by_type_and_length_within_the_limit() {
        clear();
        let v: Vec<f64> = take(4096);
        assert!(v.iter().all(|&x| x == 0.0));
        let ptr = v.as_ptr();
        recycle(v);
        assert_eq!(held_bytes(), 4096 * 8);
        // Another type or length does not get it.
        let w: Vec<f32> = take(4096);
        let u: Vec<f64> = take(4097);
        assert_eq!(held_bytes(), 4096 * 8);
        let v: Vec<f64> = take(4096);
        assert_eq!((v.as_ptr(), held_bytes()), (ptr, 0));
        // Short buffers and those beyond the limit go back to the allocator.
        recycle(vec![1.0f64; 10]);
        assert_eq!(held_bytes(), 0);
        let before = limit_bytes();
        set_limit_bytes(4096 * 8);
        recycle(v);
        recycle(u);
        assert_eq!(held_bytes(), 4096 * 8);
        set_limit_bytes(before);
        let a: ArrayD<f32> = take_array(&[64, 64]);
        recycle_array(a);
        assert_eq!(held_bytes(), 4096 * 8 + 4096 * 4);
        drop(w);
        clear();
        assert_eq!(held_bytes(), 0);
    }
}
