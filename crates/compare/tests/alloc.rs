//! The counting allocator sees allocations, frees and the peak between them.

use diffphys_compare::alloc::{CountingAllocator, HeapWindow};

#[global_allocator]
static HEAP: CountingAllocator = CountingAllocator::new();

// One test function: the counts are process-wide, so parallel tests would see
// each other's allocations.
#[test]
fn counts_current_and_peak_bytes() {
    let window = HeapWindow::start(&HEAP);
    let before = HEAP.current();
    let big = vec![1u8; 4 << 20];
    assert!(HEAP.current() >= before + (4 << 20));
    drop(big);
    // The block is gone, the peak remembers it.
    assert!(HEAP.current() < before + (1 << 20));
    assert!(window.peak_above_baseline() >= 4 << 20);

    // A fresh window forgets the earlier peak.
    let window = HeapWindow::start(&HEAP);
    let small = vec![0u64; 1000];
    let peak = window.peak_above_baseline();
    assert!((8000..1 << 20).contains(&peak), "peak {peak}");
    drop(small);

    // Growing a vector by realloc counts the new size.
    let window = HeapWindow::start(&HEAP);
    let mut v: Vec<u8> = Vec::with_capacity(16);
    v.resize(2 << 20, 0);
    assert!(window.peak_above_baseline() >= 2 << 20);
}
