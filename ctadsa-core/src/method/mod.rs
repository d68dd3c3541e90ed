//! The method: the model (hash-grid density field + Gaussians), its initialisation from the
//! views and the prior, the working box, losses, densification, the optimiser, pose refinement
//! and the training loop.

pub mod anchor_op;
pub mod blur_op;
#[cfg(feature = "wgpu")]
mod cube;
pub mod densify;
pub mod field_health;
pub mod init;
pub mod loss;
pub mod model;
pub mod ndarray_host;
pub mod optim;
mod par_buffer;
pub mod pose;
pub mod readback;
pub mod reseed;
pub mod ssim_op;
pub mod train;
pub mod training_time;
pub mod working_box;
