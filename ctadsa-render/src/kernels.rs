//! What this workspace's other op crates build their kernels from: the f32 atomic add of the
//! CubeCL kernels and zero-copy host access to NdArray tensors. Behind the `internals` feature.

#[cfg(feature = "wgpu")]
pub use crate::gpu::atomics::{Accumulator, add_f32, atomic_add_f32, atomic_add_native, has_native_f32_add};
pub use crate::ndarray_host::{host, with_host};
