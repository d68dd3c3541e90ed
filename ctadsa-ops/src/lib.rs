//! Differentiable burn ops the completion method is built from, reusable on their own: the
//! multiresolution hash encoding ([`hash_op`], [`hash_grid`]), fused linear layers
//! ([`linear_op`]), bounded scales ([`scale_op`]), the SSIM window blur ([`blur_op`]) and SSIM
//! ([`ssim_op`], [`ssim`]), the prior-anchoring neighbour search ([`anchor_op`]) and a fused Adam
//! ([`optim`]). Each op has CPU kernels for NdArray, CubeCL kernels for wgpu (feature `wgpu`) and
//! a plain-tensor or f64 reference that its tests compare it with.

pub mod anchor_op;
pub mod blur_op;
#[cfg(feature = "wgpu")]
mod cube;
pub mod error;
pub mod field_op;
pub mod hash_grid;
pub mod hash_op;
pub mod linear_op;
pub mod loss_op;
pub mod ndarray_host;
pub mod optim;
mod par_buffer;
pub mod random;
pub mod readback;
pub mod scale_op;
pub mod ssim;
pub mod ssim_op;
