//! The allocation bound of a fuzz target: a global allocator that remembers, per thread, the
//! largest single allocation asked for (the test harness runs tests on parallel threads, so a
//! process-wide figure would mix them up).
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

thread_local! {
    /// Largest allocation (bytes) this thread asked for since the last reset. Const-initialised
    /// without a destructor, so reaching it from inside the allocator never allocates.
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    let _ = LARGEST.try_with(|l| {
        if size > l.get() {
            l.set(size);
        }
    });
}

/// The system allocator, recording the largest allocation of each thread; install it in a
/// fuzz test binary with `#[global_allocator] static A: TrackingAllocator = TrackingAllocator;`
/// and measure with [`largest_allocation`].
#[derive(Debug, Clone, Copy, Default)]
pub struct TrackingAllocator;

// SAFETY: every call is forwarded unchanged to the system allocator; `note` only updates a
// thread-local counter and never allocates.
unsafe impl GlobalAlloc for TrackingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        System.alloc(layout)
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        System.alloc_zeroed(layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        System.realloc(ptr, layout, new_size)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
}

/// Runs `f` and returns its result with the largest single allocation (bytes) it made on this
/// thread. Without [`TrackingAllocator`] installed the figure is always 0.
pub fn largest_allocation<R>(f: impl FnOnce() -> R) -> (R, usize) {
    let before = LARGEST.with(|l| l.replace(0));
    let out = f();
    let largest = LARGEST.with(|l| l.replace(before.max(l.get())));
    (out, largest)
}
