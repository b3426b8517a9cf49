//! `allocator::keep_freed_memory` on glibc: large blocks come from malloc's
//! heap, not from fresh mappings. A test binary of its own, so that no other
//! test allocates while the mapped bytes are read.

#![cfg(all(target_os = "linux", target_env = "gnu"))]

/// Bytes malloc holds in mmap'd blocks.
fn mapped_bytes() -> usize {
    // SAFETY: mallinfo2 only reads malloc's counters.
    unsafe { libc::mallinfo2().hblkhd }
}

/// How many more mapped bytes malloc holds while a `len`-byte block is alive.
fn mapped_growth(len: usize) -> usize {
    let before = mapped_bytes();
    let block = std::hint::black_box(vec![1u8; len]);
    let growth = mapped_bytes().saturating_sub(before);
    drop(block);
    growth
}

#[test]
fn large_blocks_come_from_the_heap_once_the_settings_are_applied() {
    const MIB: usize = 1 << 20;
    // As glibc comes: a 16 MiB block is mapped (and its free raises the
    // dynamic threshold to its size).
    assert!(mapped_growth(16 * MIB) >= 16 * MIB, "glibc's default should map a 16 MiB block");
    // A 24 MiB block, above that raised threshold, would be mapped too...
    assert!(infer::kernels::allocator::keep_freed_memory(), "glibc refused the settings");
    // ...but with the settings it comes from the heap, and so does a block
    // above glibc's largest fixed threshold (32 MiB). (This test's thread
    // has an arena of its own, whose heaps hold at most 64 MiB: glibc maps
    // larger blocks there; the main thread's heap serves any size.)
    assert_eq!(mapped_growth(24 * MIB), 0);
    assert_eq!(mapped_growth(48 * MIB), 0);
}
