//! Counting heap allocations, for the tests that check a hot path makes none (a
//! simulator step, an environment step): an engine steps thousands of environments per
//! request on every core, where one allocation per environment-step costs more than a
//! point mass's whole step.
//!
//! A test binary installs [`CountingAllocator`] as its global allocator and wraps the
//! work in [`count_allocations`]. Only the calling thread's allocations are counted, so
//! the test harness's other threads do not disturb the count.
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOCATOR: CountingAllocator = CountingAllocator;
//! assert_eq!(count_allocations(|| step_many_times()), 0);
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The system allocator, counting the allocations and reallocations of a thread inside
/// [`count_allocations`].
pub struct CountingAllocator;

thread_local! {
    /// Allocations of this thread while counting, or `None` while not counting.
    static COUNT: Cell<Option<usize>> = const { Cell::new(None) };
}

fn note_allocation() {
    // `try_with`: threads being torn down have no thread-locals left, and count nothing.
    let _ = COUNT.try_with(|count| count.set(count.get().map(|n| n + 1)));
}

// SAFETY: every call is forwarded unchanged to the system allocator.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_allocation();
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_allocation();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Heap allocations (and reallocations) `work` makes on this thread. Counts nothing
/// unless the binary's global allocator is a [`CountingAllocator`].
pub fn count_allocations(work: impl FnOnce()) -> usize {
    COUNT.with(|count| count.set(Some(0)));
    work();
    COUNT.with(|count| count.take()).expect("counting")
}
