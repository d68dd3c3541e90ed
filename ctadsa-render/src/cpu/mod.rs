//! CPU kernels (rayon) on host slices: forward, backward, voxelisation, and pair counting.
//! They are the reference the GPU kernels are tested against.

pub(crate) mod backward;
pub(crate) mod forward;
pub(crate) mod host;
pub(crate) mod lanes;
pub(crate) mod math;
pub(crate) mod project;
pub(crate) mod splat;
pub(crate) mod transpose;
pub(crate) mod voxelize;

pub use backward::{HostGrads, render_backward};
pub use forward::{count_lanes, count_pairs, render};
pub use host::HostGaussians;
pub use voxelize::voxelize;
