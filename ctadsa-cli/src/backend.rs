//! Backend choice from the command line.

use anyhow::Result;
use burn::tensor::Device;
use clap::ValueEnum;

/// The chosen backend cannot run on this machine (the process exits with code 2).
#[derive(Debug)]
pub struct BackendUnavailable(pub String);

impl std::fmt::Display for BackendUnavailable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BackendUnavailable {}

/// Where tensors live and kernels run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendKind {
    /// CPU (burn-ndarray, rayon kernels).
    Ndarray,
    /// GPU through wgpu (Vulkan, Metal, DX12; CubeCL kernels).
    Wgpu,
}

impl BackendKind {
    /// The burn device, after checking that the backend can run here.
    #[allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is our CPU backend.
    pub fn device(self) -> Result<Device> {
        match self {
            BackendKind::Ndarray => Ok(Device::ndarray()),
            BackendKind::Wgpu => {
                #[cfg(feature = "wgpu")]
                {
                    match ctadsa_render::wgpu_adapter() {
                        Ok(name) => {
                            eprintln!("wgpu adapter: {name}");
                            Ok(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice))
                        }
                        Err(why) => Err(BackendUnavailable(format!("--backend wgpu: {why}")).into()),
                    }
                }
                #[cfg(not(feature = "wgpu"))]
                Err(BackendUnavailable("this build has no wgpu support (rebuild with the `wgpu` feature)".into())
                    .into())
            }
        }
    }
}

/// burn's default device is the first compiled backend (wgpu here), which fails on machines
/// without a GPU driver; some burn internals (optimizer state loading) allocate on it. Unless the
/// user chose otherwise, make the CPU the default. Called first thing in `main`, before any
/// thread exists.
pub fn prefer_cpu_default_device() {
    if std::env::var_os("BURN_DEVICE").is_none() {
        // SAFETY: single-threaded at this point (start of main, no threads spawned yet).
        unsafe { std::env::set_var("BURN_DEVICE", "ndarray") };
    }
}
