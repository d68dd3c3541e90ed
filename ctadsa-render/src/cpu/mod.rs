//! CPU kernels (rayon) on host slices: forward, backward, voxelisation, and pair counting.
//! They are the reference the GPU kernels are tested against.

pub mod backward;
pub mod forward;
pub mod host;
pub mod lanes;
pub mod math;
pub mod project;
pub mod splat;
pub mod transpose;
pub mod voxelize;

pub use backward::{HostGrads, render_backward};
pub use forward::{count_lanes, count_pairs, render};
pub use host::HostGaussians;
pub use voxelize::voxelize;
