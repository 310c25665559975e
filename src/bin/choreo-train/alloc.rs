//! The trainer's allocator: mimalloc, told to keep the memory it frees.

// Training allocates and frees large attention tensors every step; glibc
// hands them back to the kernel each time and page faults ate more time than
// the arithmetic (measured: 5.9 s system vs 7.6 s user over 20 steps).
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

extern "C" {
    /// mimalloc's option setter (linked in by `libmimalloc-sys`).
    fn mi_option_set(option: std::os::raw::c_int, value: std::os::raw::c_long);
}

/// Keeps freed memory mapped. mimalloc purges freed pages 10 ms after a
/// free by default, so each step's large tensors met fresh zeroed pages
/// again: a quarter of a frame-model step's samples were the kernel
/// clearing pages (bench/RESULTS.md, "Frame model training throughput":
/// with the other session 29 changes, 130 → 243–247 frames/s on one
/// thread). `mi_option_purge_delay` is 15 in the enum of
/// mimalloc 2.x and 3.x (`include/mimalloc.h`); -1 = never purge. A
/// `MIMALLOC_PURGE_DELAY` in the environment is left to decide (10 is
/// mimalloc's default: the old behaviour, for side-by-side timing).
pub fn keep_freed_memory() {
    const MI_OPTION_PURGE_DELAY: std::os::raw::c_int = 15;
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
        return;
    }
    // SAFETY: a plain option store, before any thread but this one runs.
    unsafe { mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
}
