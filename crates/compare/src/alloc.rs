//! A counting global allocator: the harness's measure of peak heap memory.
//!
//! Install it once per program (the `diffphys-compare` binary does, and so can a
//! test file) and read it around the code under measurement:
//!
//! ```no_run
//! use diffphys_compare::alloc::CountingAllocator;
//!
//! #[global_allocator]
//! static HEAP: CountingAllocator = CountingAllocator::new();
//!
//! HEAP.reset_peak();
//! let before = HEAP.current();
//! let v = vec![0u8; 1 << 20];
//! assert!(HEAP.peak() - before >= 1 << 20);
//! # drop(v);
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting the bytes currently allocated and the most
/// allocated at once since the last [`CountingAllocator::reset_peak`].
///
/// Counts are process-wide: allocations of every thread are included, so measure
/// with no other work running.
#[derive(Debug)]
pub struct CountingAllocator {
    current: AtomicUsize,
    peak: AtomicUsize,
}

impl CountingAllocator {
    /// A counter starting at zero (usable in a `static`).
    pub const fn new() -> Self {
        CountingAllocator {
            current: AtomicUsize::new(0),
            peak: AtomicUsize::new(0),
        }
    }

    /// Bytes allocated now.
    pub fn current(&self) -> usize {
        self.current.load(Ordering::Relaxed)
    }

    /// The most bytes allocated at once since the last [`Self::reset_peak`].
    pub fn peak(&self) -> usize {
        self.peak.load(Ordering::Relaxed)
    }

    /// Restarts the peak from the bytes allocated now.
    pub fn reset_peak(&self) {
        self.peak.store(self.current(), Ordering::Relaxed);
    }

    fn added(&self, bytes: usize) {
        let now = self.current.fetch_add(bytes, Ordering::Relaxed) + bytes;
        self.peak.fetch_max(now, Ordering::Relaxed);
    }

    fn removed(&self, bytes: usize) {
        self.current.fetch_sub(bytes, Ordering::Relaxed);
    }
}

impl Default for CountingAllocator {
    fn default() -> Self {
        Self::new()
    }
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged,
// so `System`'s guarantees carry over; the counters only observe sizes.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded unchanged, see above.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            self.added(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded unchanged, see above.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            self.added(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged, see above.
        unsafe { System.dealloc(ptr, layout) };
        self.removed(layout.size());
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded unchanged, see above.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            // Count the new block before releasing the old one: a moving realloc
            // briefly holds both.
            self.added(new_size);
            self.removed(layout.size());
        }
        p
    }
}

/// Peak heap bytes above a baseline, over one measured stretch of code.
#[derive(Debug, Clone, Copy)]
pub struct HeapWindow<'a> {
    heap: &'a CountingAllocator,
    baseline: usize,
}

impl<'a> HeapWindow<'a> {
    /// Starts a window: resets the peak and remembers the bytes allocated now.
    pub fn start(heap: &'a CountingAllocator) -> Self {
        heap.reset_peak();
        HeapWindow {
            heap,
            baseline: heap.current(),
        }
    }

    /// The most bytes allocated at once since [`Self::start`], above what was
    /// allocated then.
    pub fn peak_above_baseline(&self) -> usize {
        self.heap.peak().saturating_sub(self.baseline)
    }
}
