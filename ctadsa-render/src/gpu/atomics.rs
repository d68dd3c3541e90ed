//! f32 atomic adds on the GPU: the device's own instruction where it has one (Vulkan's
//! `shaderBufferFloat32AtomicAdd`: NVIDIA, AMD, Mesa lavapipe), else a compare-and-swap loop on
//! the bits, which works on every device with 32-bit integer atomics. Where many units add to one
//! address (the coarse levels of a hash grid, where every point meets the same few cells) the
//! loop's retries serialise; the native add does not retry.
//!
//! A kernel that adds atomically takes its accumulator twice, typed `Tensor<Atomic<f32>>` and
//! `Tensor<Atomic<u32>>`, and a comptime flag that says which one is real (the other is a
//! one-element placeholder); [`add_f32`] adds through the one the flag names, and the launcher
//! picks the flag with `launches_native` and the arguments with [`Accumulator`].

use burn_cubecl::cubecl;
use burn_cubecl::tensor::CubeTensor;
use cubecl::ir::features::AtomicUsage;
use cubecl::ir::{ElemType, FloatKind, Type};
use cubecl::prelude::*;

use crate::F32Add;

/// Whether the device of `like` adds f32 atomically in hardware.
pub fn has_native_f32_add(like: &CubeTensor) -> bool {
    like.client.properties().atomic_type_usage(Type::atomic(ElemType::Float(FloatKind::F32))).contains(AtomicUsage::Add)
}

/// Whether to launch the native variant on the device of `like`: where the device has it,
/// unless `requested` asks for the loop.
pub fn launches_native(like: &CubeTensor, requested: F32Add) -> bool {
    requested == F32Add::Auto && has_native_f32_add(like)
}

/// A kernel's accumulator bound as its two typed arguments.
pub struct Accumulator {
    /// The variant the kernel is compiled for (its comptime `native` flag).
    pub native: bool,
    /// The `Tensor<Atomic<f32>>` argument (the placeholder unless native).
    pub as_f32: CubeTensor,
    /// The `Tensor<Atomic<u32>>` argument (the placeholder when native).
    pub as_u32: CubeTensor,
}

impl Accumulator {
    /// `target` (f32, zero-initialised or holding the sums to add to) bound for the variant
    /// `launches_native` picks on its device.
    pub fn new(target: &CubeTensor, requested: F32Add) -> Self {
        use burn::backend::ops::FloatTensorOps;
        use burn::backend::{FloatDType, Shape};
        // Never read or written (the kernel's comptime branch drops the other argument's use).
        let placeholder = burn_cubecl::CubeBackend::float_empty(Shape::from(vec![1]), &target.device, FloatDType::F32);
        if launches_native(target, requested) {
            Self { native: true, as_f32: target.clone(), as_u32: placeholder }
        } else {
            Self { native: false, as_f32: placeholder, as_u32: target.clone() }
        }
    }
}

/// Adds `value` to element `index` of the accumulator: through `as_f32` with the native add when
/// `native`, else through `as_u32` with the loop (the branch is resolved at compile time).
#[cube]
pub fn add_f32(
    as_f32: &mut Tensor<Atomic<f32>>,
    as_u32: &mut Tensor<Atomic<u32>>,
    index: usize,
    value: f32,
    #[comptime] native: bool,
) {
    if native {
        atomic_add_native(&mut as_f32[index], value);
    } else {
        atomic_add_f32(&mut as_u32[index], value);
    }
}

/// Adds `value` to `*ptr` with the device's f32 atomic add.
#[cube]
pub fn atomic_add_native(ptr: &mut Atomic<f32>, value: f32) {
    if value != 0.0 {
        ptr.fetch_add(value);
    }
}

/// Adds `value` to the f32 whose bits are `*ptr` with a compare-and-swap loop.
#[cube]
pub fn atomic_add_f32(ptr: &mut Atomic<u32>, value: f32) {
    if value != 0.0 {
        let mut v = ptr.load();
        loop {
            let prev = v;
            let new = (f32::from_bits(v) + value).to_bits();
            v = ptr.compare_exchange_weak(v, new);
            if prev == v {
                break;
            }
        }
    }
}
