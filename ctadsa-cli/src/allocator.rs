//! glibc malloc settings for training: keep large freed blocks for reuse.
//!
//! A training step allocates and frees tens of buffers of 1–70 MB (activations, gradients, the
//! hash encoding's Jacobian). With glibc's defaults each thread's arena hands the large ones back
//! to the kernel on free and the next step faults them in again page by page (`perf`: 13 % of a
//! paper-scale step in page faults). One arena, a fixed mmap threshold and no trimming keep them
//! in the heap: `ctadsa bench train --config configs/baselines/paper-method.toml` 214 → 190 ms
//! per step, the peak resident memory unchanged (docs/PERFORMANCE.md). The same settings can be
//! given to any program through `MALLOC_ARENA_MAX=1 MALLOC_MMAP_THRESHOLD_=33554432
//! MALLOC_TRIM_THRESHOLD_=2147483647`.

/// Applies the settings; call first thing in `main`, before any thread exists. Settings the
/// user gave through `MALLOC_*` environment variables are left alone.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let settings = [
            ("MALLOC_ARENA_MAX", libc::M_ARENA_MAX, 1),
            ("MALLOC_MMAP_THRESHOLD_", libc::M_MMAP_THRESHOLD, 32 << 20),
            ("MALLOC_TRIM_THRESHOLD_", libc::M_TRIM_THRESHOLD, i32::MAX),
        ];
        for (variable, parameter, value) in settings {
            if std::env::var_os(variable).is_none() {
                // SAFETY: mallopt only changes the allocator's parameters; it is called before
                // any other thread exists, and an unsupported value is reported (ignored here:
                // the defaults stay, which is correct, only slower).
                unsafe { libc::mallopt(parameter, value) };
            }
        }
    }
}
