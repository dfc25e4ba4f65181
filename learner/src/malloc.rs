//! glibc `malloc` settings for the learner's allocation pattern.
//!
//! Every D/Q and PPO step allocates and frees dozens of activation tensors of
//! 0.2-1.5 MB (libtorch's CPU allocator is `posix_memalign`). glibc serves blocks that
//! large with `mmap` and returns them with `munmap` or a heap trim, so each step paid
//! for fresh zero-filled pages: ~15% of a D/Q step was page faults in the kernel
//! (`bench/learner.md`). Raising the mmap threshold to glibc's maximum (32 MiB) and the
//! trim threshold to 256 MiB keeps freed blocks in the heap for the next step. The
//! cost is up to 256 MiB of freed memory the process keeps instead of returning.

/// Applies the settings (glibc on Linux; elsewhere nothing). Call it once at start.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        const MMAP_THRESHOLD: libc::c_int = 32 << 20;
        const TRIM_THRESHOLD: libc::c_int = 256 << 20;
        // SAFETY: mallopt only changes allocator parameters; any value is accepted or
        // refused (return 0), never undefined behaviour.
        let ok = unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
        };
        if !ok {
            tracing::debug!("glibc refused the malloc thresholds; keeping its defaults");
        }
    }
}
