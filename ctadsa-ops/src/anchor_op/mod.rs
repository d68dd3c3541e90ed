//! Prior anchoring's targets as a backend op: for sampled Gaussian centres, the mean of the `k`
//! nearest prior-surface points and whether the nearest is within the anchoring radius. On the
//! GPU the search runs in a kernel (no read-back of the centres in the training step); on the
//! CPU the same search runs over the same grid (`grid.rs`), which is also the kernel's oracle.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

#[cfg(feature = "wgpu")]
mod gpu;
pub mod grid;
mod loss;

pub use loss::{anchor_loss, composed as anchor_loss_composed};

use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, Dispatch, ExtensionType, NdArray, TensorMetadata, backend_extension,
    tensor::FloatTensor,
};
use burn::tensor::{Device, Tensor, TensorData};

use crate::ndarray_host::with_host;
use grid::{AnchorGrid, GridView};

/// The scalars of a search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorSearch {
    /// The grid's cell (0, 0, 0) corner (mm) and cell side (mm).
    pub origin: [f32; 3],
    pub cell_mm: f32,
    /// Neighbours averaged (at most [`grid::MAX_K`]).
    pub k: usize,
    /// Anchoring radius (mm).
    pub radius_mm: f32,
}

/// Targets `[m, 3]` (mm) and keep flags `[m]` (1: anchored).
#[derive(ExtensionType)]
pub struct AnchorTargets<B: Backend> {
    pub targets: FloatTensor<B>,
    pub keep: FloatTensor<B>,
}

/// Backend operation of the anchor search.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait AnchorBackend: Backend {
    /// For `queries` `[m, 3]`, the grid's `points` `[M, 3]` and hash `table` `[slots · 5]`.
    fn anchor_targets(
        queries: FloatTensor<Self>,
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        search: AnchorSearch,
    ) -> AnchorTargets<Self>;
}

impl AnchorBackend for NdArray {
    fn anchor_targets(
        queries: FloatTensor<Self>,
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        search: AnchorSearch,
    ) -> AnchorTargets<Self> {
        let device = queries.device();
        let m = queries.shape()[0];
        let (targets, keep) = with_host(&queries, |q| {
            with_host(&points, |points| {
                with_host(&table, |table| {
                    let view = GridView { origin: search.origin, cell_mm: search.cell_mm, points, table };
                    view.targets(q, search.k, search.radius_mm)
                })
            })
        });
        AnchorTargets {
            targets: Self::float_from_data(TensorData::new(targets, [m, 3]), &device),
            keep: Self::float_from_data(TensorData::new(keep, [m]), &device),
        }
    }
}

#[cfg(feature = "wgpu")]
impl AnchorBackend for burn_cubecl::CubeBackend {
    fn anchor_targets(
        queries: FloatTensor<Self>,
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        search: AnchorSearch,
    ) -> AnchorTargets<Self> {
        gpu::anchor_targets(queries, points, table, search)
    }
}

impl<B: Backend + AnchorBackend, C: burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy> AnchorBackend
    for Autodiff<B, C>
{
    fn anchor_targets(
        queries: FloatTensor<Self>,
        points: FloatTensor<Self>,
        table: FloatTensor<Self>,
        search: AnchorSearch,
    ) -> AnchorTargets<Self> {
        let out = B::anchor_targets(queries.into_primitive(), points.into_primitive(), table.into_primitive(), search);
        AnchorTargets { targets: Self::from_inner(out.targets), keep: Self::from_inner(out.keep) }
    }
}

/// A grid of prior-surface points on a device, for [`anchor_targets`].
#[derive(Debug, Clone)]
pub struct DeviceGrid {
    points: Tensor<2>,
    table: Tensor<1>,
    search: AnchorSearch,
}

impl DeviceGrid {
    /// `grid` uploaded to `device`, searched for `k` neighbours within `radius_mm`.
    pub fn new(grid: &AnchorGrid, k: usize, radius_mm: f64, device: &Device) -> Self {
        let m = grid.points.len() / 3;
        let points = Tensor::<2>::from_data(TensorData::new(grid.points.clone(), [m, 3]), device);
        let table = Tensor::<1>::from_data(TensorData::new(grid.table.clone(), [grid.table.len()]), device);
        let search = AnchorSearch { origin: grid.origin, cell_mm: grid.cell_mm, k, radius_mm: radius_mm as f32 };
        Self { points, table, search }
    }
}

/// Targets `[m, 3]` and keep flags `[m]` of `queries` `[m, 3]` (mm; not differentiated).
pub fn anchor_targets(queries: Tensor<2>, grid: &DeviceGrid) -> (Tensor<2>, Tensor<1>) {
    let out = <Dispatch as AnchorBackend>::anchor_targets(
        queries.detach().into_dispatch(),
        grid.points.clone().into_dispatch(),
        grid.table.clone().into_dispatch(),
        grid.search,
    );
    (Tensor::from_dispatch(out.targets), Tensor::from_dispatch(out.keep))
}
