//! An allocator that refuses any single allocation above a cap, so a reader
//! that trusts a declared size (`POINTS 1000000000000`) is caught as such
//! instead of swapping the machine, and says which case it was running.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The largest single allocation a parser may make on fuzz input.
pub static CAP_BYTES: AtomicUsize = AtomicUsize::new(1 << 30);

thread_local! {
    /// The target and case this thread is running, for the report.
    pub static CURRENT: Cell<(&'static str, u64)> = const { Cell::new(("", 0)) };
}

pub struct CappedAllocator;

// SAFETY: every call is forwarded to the system allocator unchanged, except
// that oversized requests return null (which the caller reports as an
// allocation failure, as it would for an exhausted machine).
unsafe impl GlobalAlloc for CappedAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if refused(layout.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if refused(layout.size()) {
            return std::ptr::null_mut();
        }
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if refused(new_size) {
            return std::ptr::null_mut();
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Whether an allocation of `size` bytes is over the cap; if so, says so.
fn refused(size: usize) -> bool {
    if size <= CAP_BYTES.load(Ordering::Relaxed) {
        return false;
    }
    // Formatting a few words allocates far below the cap.
    let (target, case) = CURRENT.try_with(Cell::get).unwrap_or(("", 0));
    eprintln!("fuzz: an allocation of {size} bytes was refused in target `{target}`, case {case}");
    true
}
