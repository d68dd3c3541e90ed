//! CPU kernels (rayon) on host slices: forward, backward, voxelisation, and pair counting.
//! They are the reference the GPU kernels are tested against.

pub(crate) mod backward;
#[cfg(feature = "internals")]
mod counts;
pub(crate) mod forward;
pub(crate) mod host;
pub(crate) mod lanes;
pub(crate) mod math;
pub(crate) mod project;
pub(crate) mod splat;
pub(crate) mod transpose;
pub(crate) mod voxelize;

#[cfg(feature = "internals")]
pub use backward::HostGrads;
pub use backward::render_backward;
#[cfg(feature = "internals")]
pub use counts::{count_lanes, count_pairs};
pub use forward::render;
pub use host::HostGaussians;
pub use voxelize::voxelize;
