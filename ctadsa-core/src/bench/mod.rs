//! Benchmarks as library code: they return typed figures, the CLI prints them.
//!
//! - [`train`]: the training step by stage, with its device work (launches, reads, uploads);
//! - `launches` (wgpu builds): kernel launches counted, and timed on the device, per kernel.

#[cfg(feature = "wgpu")]
mod launches;
pub mod train;

#[cfg(feature = "wgpu")]
pub use launches::{KernelLaunches, LaunchWatch};

/// Kernel launches per kernel (this build has no CubeCL backend: always empty).
#[cfg(not(feature = "wgpu"))]
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KernelLaunches {
    /// Kernel name → launches.
    pub counts: std::collections::BTreeMap<String, u64>,
    /// Kernel name → device time.
    pub device_time: std::collections::BTreeMap<String, std::time::Duration>,
}

pub use train::{TrainBenchReport, TrainBenchSettings, bench_train};
