//! The method: the model (hash-grid density field + Gaussians), its initialisation from the
//! views and the prior, the working box, losses, densification, pose refinement and the training
//! loop. The differentiable ops it is built from (hash encoding, fused linear layers, blur, SSIM,
//! the anchor search, Adam) are `ctadsa_ops`.

pub mod arrival;
pub mod densify;
pub mod field_health;
pub mod init;
pub mod loss;
pub mod model;
pub mod pose;
pub mod reseed;
pub(crate) mod seed_growth;
pub(crate) mod tracking;
pub mod train;
pub mod training_time;
pub mod working_box;
