//! Benchmarks as library code: they return typed figures, the CLI prints them.
//!
//! - [`train`]: the training step by stage, with its device work (launches, reads, uploads);
//! - [`render`]: the renderer's kernels and op, and the voxel projector, against plastimatch
//!   ([`plastimatch`]);
//! - `launches` (wgpu builds): kernel launches counted, and timed on the device, per kernel.

#[cfg(feature = "wgpu")]
mod launches;
pub mod plastimatch;
pub mod render;
pub mod train;

#[cfg(feature = "wgpu")]
pub use launches::LaunchWatch;

use std::collections::BTreeMap;
use std::time::Duration;

/// Launches (and device time) per kernel over the observed work (empty in a build without a
/// CubeCL backend).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KernelLaunches {
    /// Kernel name (short, without module path and generics) → launches.
    pub counts: BTreeMap<String, u64>,
    /// Kernel name → device time (only when timed, and only launches the device timed).
    pub device_time: BTreeMap<String, Duration>,
}

impl KernelLaunches {
    /// All launches.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }

    /// All timed device time.
    pub fn total_device_time(&self) -> Duration {
        self.device_time.values().sum()
    }
}

pub use train::{TrainBenchReport, TrainBenchSettings, bench_train};

/// Peak resident memory of this process (MiB), from /proc (Linux); `None` elsewhere.
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Resets the peak resident memory to the present one (Linux `clear_refs` 5), so that
/// [`peak_rss_mib`] measures from here on; false where the kernel does not allow it.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}
