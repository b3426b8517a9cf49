//! The process's allocator told to keep freed memory for reuse.
//!
//! Why: a training step allocates and frees the same activation and
//! gradient buffers, tens of megabytes each, every step. glibc's malloc
//! serves such blocks with `mmap` and unmaps them on free (or trims its
//! heap), so each step asks the kernel for fresh pages and takes a page
//! fault, and a page of zeroing, on first touch of every 4 KiB: on a VGG16
//! step that was a fifth of the time. With a fixed mmap threshold at
//! glibc's largest and trimming only above 2 GiB of free memory, blocks go
//! back to malloc's free lists and the next step reuses them. glibc caps
//! that threshold at 32 MiB, and AlexNet's fully connected weight gradients
//! are larger, so mmap is also switched off (glibc still maps a block a
//! heap cannot hold: above 64 MiB in a thread's own arena). The cost: the process keeps
//! the memory of its peak until it exits.

/// Applies the settings; `true` where they took (glibc on Linux), `false`
/// where this allocator is not glibc's (nothing changed).
pub fn keep_freed_memory() -> bool {
    imp::keep_freed_memory()
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
mod imp {
    /// glibc refuses a fixed mmap threshold above half its arena heap size
    /// (64 MiB on 64-bit systems).
    const MMAP_THRESHOLD: i32 = 32 << 20;
    /// `mallopt` takes an `int`: the largest trim threshold it can express.
    const TRIM_THRESHOLD: i32 = i32::MAX;
    /// No block is served by its own mapping while the heap can grow.
    const MMAP_MAX: i32 = 0;

    pub fn keep_freed_memory() -> bool {
        // SAFETY: mallopt only changes malloc's tunables; it takes malloc's
        // own lock and is safe to call at any time.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
                && libc::mallopt(libc::M_MMAP_MAX, MMAP_MAX) == 1
        }
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
mod imp {
    pub fn keep_freed_memory() -> bool {
        false
    }
}
