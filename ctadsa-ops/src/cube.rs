//! Glue the method's CubeCL kernels share: operands as the kernels index them, outputs without
//! a fill, and the launch size of one unit per element.

use burn::backend::ops::FloatTensorOps;
use burn::backend::{FloatDType, TensorMetadata};
use burn::tensor::{DType, Shape};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

/// An f32, contiguous copy of `t` (no copy when it already is), as the kernels index it.
pub(crate) fn prepare(t: CubeTensor) -> CubeTensor {
    let t = if t.dtype() == DType::F32 { t } else { CubeBackend::float_cast(t, FloatDType::F32) };
    into_contiguous(t)
}

/// An uninitialised f32 tensor on the device of `like`, for an output a kernel writes whole.
pub(crate) fn empty(shape: Vec<usize>, like: &CubeTensor) -> CubeTensor {
    CubeBackend::float_empty(Shape::from(shape), &like.device, FloatDType::F32)
}

/// Cubes of `units_per_cube` units covering `len` units, one per element.
pub(crate) fn launch_1d(like: &CubeTensor, len: usize, units_per_cube: u32) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new_1d(units_per_cube);
    (cubecl::calculate_cube_count_elemwise(&like.client, len, dim), dim)
}
