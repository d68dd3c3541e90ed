#![doc = include_str!("../README.md")]
// `!(x >= y)` is our NaN-rejecting comparison idiom (NaN fails it); keep it.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

mod autodiff;
/// The CPU kernels on host slices (benchmarks and tests); the op is the supported API.
#[doc(hidden)]
pub mod cpu;
mod error;
pub mod geometry;
#[cfg(feature = "wgpu")]
pub mod gpu;
mod grid;
mod host_backend;
pub mod ndarray_host;
pub mod ops;
/// f64 reference implementations: the test oracle of the kernels.
#[doc(hidden)]
pub mod reference;
mod view_params;

use std::sync::Arc;

use burn::backend::Dispatch;
use burn::tensor::{Tensor, TensorData};

pub use error::RenderError;
pub use geometry::{ConeBeamView, Intrinsics, MAX_DETECTOR_PX, TigreGeometry};
pub use grid::VoxelGrid;
pub use ops::{RenderSetup, XrayBackend};
pub use view_params::{VIEW_PARAMS_LEN, ViewParams};

/// Settings of a render call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Footprint cut-off `k` in standard deviations (default 3): a ray farther than `k`
    /// Mahalanobis units from a Gaussian's centre does not see it (the neglected tail is at most
    /// `e^{−k²/2}` of that ray's peak, 1.1% for k = 3). Must be in `(0, 20]`.
    pub k_sigma: f32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { k_sigma: 3.0 }
    }
}

impl RenderSettings {
    fn validate(&self) -> Result<(), RenderError> {
        if !(self.k_sigma > 0.0 && self.k_sigma <= 20.0) {
            return Err(RenderError::InvalidSetting(format!("k_sigma must be in (0, 20], got {}", self.k_sigma)));
        }
        Ok(())
    }
}

/// A set of views rendered together; all have the same detector size.
#[derive(Debug, Clone)]
pub struct ViewSet {
    views: Arc<[ConeBeamView]>,
    packed: Arc<[ViewParams]>,
}

impl ViewSet {
    /// Checks that there is at least one view and that all have the same size.
    pub fn new(views: Vec<ConeBeamView>) -> Result<Self, RenderError> {
        let first = views.first().ok_or(RenderError::NoViews)?;
        let expected = (first.width(), first.height());
        for (index, v) in views.iter().enumerate() {
            let got = (v.width(), v.height());
            if got != expected {
                return Err(RenderError::MixedViewSizes { index, expected, got });
            }
        }
        let packed = views.iter().map(ViewParams::new).collect();
        Ok(Self { views: views.into(), packed })
    }

    /// The views.
    pub fn views(&self) -> &[ConeBeamView] {
        &self.views
    }

    /// Number of views `V`.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// Always false (a view set has at least one view).
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// `(width, height)` of every view, in pixels.
    pub fn image_size(&self) -> (u32, u32) {
        (self.views[0].width(), self.views[0].height())
    }

    /// The views packed as f32 for the kernels.
    pub fn packed(&self) -> &[ViewParams] {
        &self.packed
    }

    /// The subset of views with the given indices (in that order).
    pub fn select(&self, indices: &[usize]) -> Result<Self, RenderError> {
        let views = indices
            .iter()
            .map(|&i| {
                self.views.get(i).copied().ok_or_else(|| {
                    RenderError::InvalidSetting(format!("view index {i} out of range (have {})", self.len()))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(views)
    }

    fn setup(&self, settings: &RenderSettings) -> RenderSetup {
        RenderSetup { views: self.packed.clone(), k_sigma: settings.k_sigma }
    }
}

/// The Gaussian parameters of a scene, `N` Gaussians.
#[derive(Debug, Clone)]
pub struct Gaussians {
    /// Centres `[N, 3]` (mm, world).
    pub means: Tensor<2>,
    /// Standard deviations along the local axes `[N, 3]` (mm, > 0).
    pub scales: Tensor<2>,
    /// Rotations `[N, 4]` as quaternions `(w, x, y, z)`; normalised inside the op.
    pub rotations: Tensor<2>,
    /// Central densities `[N]` (per mm: a pixel value is density × mm).
    pub densities: Tensor<1>,
}

impl Gaussians {
    /// Number of Gaussians `N`, after checking that the four tensors agree in shape.
    pub fn check_shapes(&self) -> Result<usize, RenderError> {
        let n = self.densities.dims()[0];
        let expect = |name: &'static str, got: Vec<usize>, cols: usize| {
            if got == [n, cols] {
                Ok(())
            } else {
                Err(RenderError::Shape { name, expected: format!("[{n}, {cols}]"), got })
            }
        };
        expect("means", self.means.dims().to_vec(), 3)?;
        expect("scales", self.scales.dims().to_vec(), 3)?;
        expect("rotations", self.rotations.dims().to_vec(), 4)?;
        Ok(n)
    }

    /// Reads the parameters back (a device sync) and reports the first Gaussian with a
    /// non-finite value, a non-positive scale, a negative density or a zero quaternion.
    /// The kernels themselves skip such Gaussians, so this is for reporting, not safety.
    pub fn validate(&self) -> Result<(), RenderError> {
        let n = self.check_shapes()?;
        let read = |t: TensorData| -> Result<Vec<f32>, RenderError> {
            t.convert::<f32>().try_to_vec::<f32>().map_err(|e| RenderError::Readback(format!("{e:?}")))
        };
        let means = read(self.means.clone().into_data())?;
        let scales = read(self.scales.clone().into_data())?;
        let rotations = read(self.rotations.clone().into_data())?;
        let densities = read(self.densities.clone().into_data())?;
        for i in 0..n {
            let bad = |problem: String| Err(RenderError::InvalidGaussian { index: i, problem });
            let m = &means[3 * i..3 * i + 3];
            let s = &scales[3 * i..3 * i + 3];
            let q = &rotations[4 * i..4 * i + 4];
            if !m.iter().all(|v| v.is_finite()) {
                return bad(format!("non-finite mean {m:?}"));
            }
            if !s.iter().all(|v| v.is_finite() && *v > 0.0) {
                return bad(format!("scales must be positive and finite, got {s:?}"));
            }
            if !q.iter().all(|v| v.is_finite()) || q.iter().map(|v| v * v).sum::<f32>() < 1e-24 {
                return bad(format!("quaternion must be finite and non-zero, got {q:?}"));
            }
            let d = densities[i];
            if !(d.is_finite() && d >= 0.0) {
                return bad(format!("density must be finite and ≥ 0, got {d}"));
            }
        }
        Ok(())
    }
}

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
        settings.k_sigma,
    )))
}
