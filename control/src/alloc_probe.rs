//! Proof of fixed allocation: a global allocator that forwards to the system allocator and counts
//! allocations and frees per thread. Tests and benches install it (`#[global_allocator]`) and
//! compare [`counts`] around the hot path; the deployed binary does not install it.
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    // Per thread, so parallel tests and the log writer thread do not disturb the control thread's count.
    static COUNT: Cell<(usize, usize)> = const { Cell::new((0, 0)) };
}

/// Allocations (including reallocations) and frees made by the calling thread so far.
pub fn counts() -> (usize, usize) {
    COUNT.with(|c| c.get())
}

/// The counting allocator: `#[global_allocator] static A: CountingAlloc = CountingAlloc;`.
pub struct CountingAlloc;

// SAFETY: every method forwards its arguments unchanged to `System`, which upholds the
// `GlobalAlloc` contract; the counters are thread-locals of `Copy` data that never allocate.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        COUNT.with(|c| c.set((c.get().0 + 1, c.get().1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        COUNT.with(|c| c.set((c.get().0, c.get().1 + 1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        COUNT.with(|c| c.set((c.get().0 + 1, c.get().1 + 1)));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}
