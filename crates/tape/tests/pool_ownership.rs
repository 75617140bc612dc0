//! Memory belongs to whoever allocated it: a dropped tape returns every byte it
//! took, a pool passed by the caller keeps buffers across tapes until the caller
//! drops it. Measured with a counting global allocator that counts the live
//! bytes of each thread apart: the test harness's other threads allocate and
//! free while a test runs (a process-wide count once read −84 bytes), and each
//! test records, sweeps and drops on its own thread (arrays this small never
//! reach the parallel kernels).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use diffphys_tape::pool::BufferPool;
use diffphys_tape::{test_array, ArrayD, Tape};

struct Counting;

thread_local! {
    /// This thread's allocated minus freed bytes.
    static LIVE: Cell<isize> = const { Cell::new(0) };
}

/// Adds `delta` to this thread's count (nothing once the thread's locals are
/// gone, as it exits).
fn count(delta: isize) {
    let _ = LIVE.try_with(|l| l.set(l.get() + delta));
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count(layout.size() as isize);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        count(-(layout.size() as isize));
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count(layout.size() as isize);
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count(new_size as isize - layout.size() as isize);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// This thread's live bytes.
fn live() -> isize {
    LIVE.with(Cell::get)
}

const N: usize = 100_000;

/// Records `Σ (x² + x)·x` on `tape`, sweeps it back and checks the gradient
/// `3x² + 2x`; returns nothing the tape owns.
fn record(tape: &Tape<f64>, x0: &ArrayD<f64>) {
    let x = tape.var(x0.clone());
    let y = x.mul(x).unwrap().add(x).unwrap().mul(x).unwrap();
    let g = tape.backward(y.sum().unwrap(), &[x]).unwrap();
    let got = g.get(x).unwrap();
    let worst = got
        .iter()
        .zip(x0)
        .map(|(g, x)| (g - (3.0 * x * x + 2.0 * x)).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "{worst}");
}

#[test]
fn a_dropped_tape_returns_all_its_memory() {
    let x0 = test_array::<f64>(&[N], 3);
    // Warm up the thread-local bookkeeping (the current-pool stack).
    record(&Tape::new(), &x0);
    let before = live();
    let tape = Tape::<f64>::new();
    record(&tape, &x0);
    let during = live() - before;
    // x, x², x² + x, (x² + x)·x at least.
    assert!(during >= (4 * N * 8) as isize, "{during}");
    drop(tape);
    assert_eq!(live() - before, 0, "bytes kept after the tape was dropped");
}

#[test]
fn a_pool_the_caller_holds_serves_the_next_tape_and_goes_with_the_caller() {
    let x0 = test_array::<f64>(&[N], 5);
    record(&Tape::new(), &x0);
    let before = live();
    let pool = BufferPool::new();
    record(&Tape::with_pool(&pool), &x0);
    let held = pool.held_bytes();
    // The first tape's values and consumed gradients wait in the pool.
    assert!(held >= 3 * N * 8, "{held}");
    // What the process holds beyond the baseline is those buffers and the
    // pool's small bookkeeping (its map and the boxes around buffers).
    let kept = live() - before;
    assert!(
        kept >= held as isize && kept <= held as isize + 16 * 1024,
        "{kept} vs {held}"
    );

    // A second tape on the installed pool takes its buffers from it: its
    // values add at most its own leaf to what the process holds.
    let high = live();
    pool.scope(|| {
        let tape = Tape::new();
        assert!(tape.pool().same_as(&pool));
        record(&tape, &x0);
    });
    assert!(
        live() - high <= (N * 8) as isize + 4096,
        "{}",
        live() - high
    );

    drop(pool);
    assert_eq!(live() - before, 0, "bytes kept after the pool was dropped");
}

#[test]
fn a_pool_keeps_no_more_than_its_limit() {
    let x0 = test_array::<f64>(&[N], 7);
    let pool = BufferPool::with_limit_bytes(2 * N * 8);
    record(&Tape::with_pool(&pool), &x0);
    assert!(pool.held_bytes() <= 2 * N * 8, "{}", pool.held_bytes());
    let none = BufferPool::with_limit_bytes(0);
    record(&Tape::with_pool(&none), &x0);
    assert_eq!(none.held_bytes(), 0);
}
