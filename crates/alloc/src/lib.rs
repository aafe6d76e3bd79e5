//! The allocator every fusiondet process runs with, and its one option: the binary and the
//! benchmarks (whose figures must be the binary's) declare it the same way.
//!
//! mimalloc instead of the system allocator: the networks allocate and free many
//! multi-megabyte tensors per frustum batch, which glibc's malloc serves with fresh
//! mmap/munmap pairs and page faults (a third of SAF's detection time went to the kernel;
//! see docs/performance.md). mimalloc keeps such blocks for reuse.
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOCATOR: fusiondet_alloc::MiMalloc = fusiondet_alloc::MiMalloc;
//! fn main() {
//!     fusiondet_alloc::keep_freed_memory();
//! }
//! ```

pub use mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its place in `mi_option_e`, mimalloc 3.3 as
/// Cargo.lock pins it; libmimalloc-sys names no constant for it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps freed memory committed instead of returning it to the kernel a second later
/// (mimalloc 3's default purge delay): a training step frees and allocates the same large
/// tensors every step, and each return made the next step fault and zero those pages again.
/// Measured on a DASANet training process: 15% less wall time, a third of the system time, 5%
/// more peak memory (docs/performance.md). `MIMALLOC_PURGE_DELAY` in the environment still
/// decides. Call it first thing in `main`.
pub fn keep_freed_memory() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's options; any value is valid for this one.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The option index is mimalloc's purge delay: its default in mimalloc 3.3's
    /// `options.c` is 1,000 ms (the header's comment still says 10), and setting it reads
    /// back.
    #[test]
    fn the_purge_delay_option_is_the_one_set() {
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            return;
        }
        // SAFETY: reads and sets one of mimalloc's options.
        let before = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(before, 1000);
        keep_freed_memory();
        let after = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(after, -1);
    }
}
