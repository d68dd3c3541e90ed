#![doc = include_str!("../README.md")]
// `!(x >= y)` is our NaN-rejecting comparison idiom (NaN fails it); keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod autodiff;
mod error;
mod gaussians;
pub mod geometry;
#[cfg(feature = "wgpu")]
mod gpu;
mod grid;
mod host_backend;
mod ndarray_host;
mod ops;
mod settings;
mod view_params;
mod views;

// The kernel layer: public only with the `internals` feature (this workspace's op crates, tests
// and benchmarks), with no stability promise; the op above is the supported API.
#[cfg(feature = "internals")]
pub mod cpu;
#[cfg(not(feature = "internals"))]
mod cpu;
#[cfg(feature = "internals")]
pub mod kernels;
#[cfg(feature = "internals")]
pub mod reference;

use burn::backend::Dispatch;
use burn::tensor::Tensor;

pub use error::RenderError;
pub use gaussians::Gaussians;
pub use geometry::{ConeBeamView, Intrinsics, MAX_ANGLE_DEG, MAX_DETECTOR_PX, TigreGeometry};
#[cfg(feature = "wgpu")]
pub use gpu::probe::{REQUIRED_FEATURE, wgpu_adapter};
pub use grid::VoxelGrid;
pub use ops::{RenderGrads, RenderSetup, XrayBackend};
pub use settings::{F32Add, RenderSettings};
pub use view_params::{VIEW_PARAMS_LEN, ViewParams};
pub use views::ViewSet;

fn dispatch_render(g: &Gaussians, probe: Tensor<2>, setup: RenderSetup) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as XrayBackend>::xray_render(
        g.means.clone().into_dispatch(),
        g.scales.clone().into_dispatch(),
        g.rotations.clone().into_dispatch(),
        g.densities.clone().into_dispatch(),
        probe.into_dispatch(),
        setup,
    ))
}

/// Renders the Gaussians into every view: `[V, H, W]` line integrals (density × mm).
///
/// Differentiable with respect to all four parameter tensors when they are on an autodiff
/// device. Shapes are checked (no device sync); values are not — non-finite or degenerate
/// Gaussians contribute nothing (see [`Gaussians::validate`] to report them).
pub fn render(g: &Gaussians, views: &ViewSet, settings: &RenderSettings) -> Result<Tensor<3>, RenderError> {
    settings.validate()?;
    let n = g.check_shapes()?;
    let probe = Tensor::zeros([n, 2], &g.means.device());
    Ok(dispatch_render(g, probe, views.setup(settings)))
}

/// Like [`render`], and the gradient that reaches `screen_probe` (`[N, 2]`, e.g. zeros with
/// `require_grad`) is the densification statistic: per Gaussian, column 0 is the sum over the
/// views of `‖∂L/∂(projected centre)‖` in NDC units (pixel gradient × half the image size, as in
/// 3DGS), column 1 the number of views whose image the Gaussian touched.
pub fn render_with_stats(
    g: &Gaussians,
    screen_probe: Tensor<2>,
    views: &ViewSet,
    settings: &RenderSettings,
) -> Result<Tensor<3>, RenderError> {
    settings.validate()?;
    let n = g.check_shapes()?;
    if screen_probe.dims() != [n, 2] {
        return Err(RenderError::Shape {
            name: "screen_probe",
            expected: format!("[{n}, 2]"),
            got: screen_probe.dims().to_vec(),
        });
    }
    Ok(dispatch_render(g, screen_probe, views.setup(settings)))
}

/// The density field of the Gaussians at the voxel centres of `grid`: `[X, Y, Z]`, each
/// Gaussian cut off at `k_sigma` standard deviations. Not differentiable.
pub fn voxelize(g: &Gaussians, grid: &VoxelGrid, settings: &RenderSettings) -> Result<Tensor<3>, RenderError> {
    settings.validate()?;
    grid.validate()?;
    g.check_shapes()?;
    Ok(Tensor::from_dispatch(<Dispatch as XrayBackend>::xray_voxelize(
        g.means.clone().into_dispatch(),
        g.scales.clone().into_dispatch(),
        g.rotations.clone().into_dispatch(),
        g.densities.clone().into_dispatch(),
        *grid,
        *settings,
    )))
}
