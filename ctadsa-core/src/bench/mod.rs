//! Benchmarks as library code: they return typed figures, the CLI prints them.
//!
//! - [`train`]: the training step by stage, with its device work (launches, reads, uploads);
//! - `launches` (wgpu builds): kernel launches counted, and timed on the device, per kernel.

#[cfg(feature = "wgpu")]
mod launches;
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
