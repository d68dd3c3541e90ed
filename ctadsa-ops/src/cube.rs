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

/// Whether `device` runs CubeCL kernels (wgpu), with or without autodiff.
pub(crate) fn runs_on_cube(device: &burn::tensor::Device) -> bool {
    matches!(device.clone().without_autodiff().as_dispatch(), burn::backend::DispatchDevice::Cube(_))
}

/// Units of the one-workgroup reductions (`2^REDUCE_LEVELS`).
pub(crate) const REDUCE_UNITS: usize = 256;
pub(crate) const REDUCE_LEVELS: u32 = 8;

/// Sums `values[0..units]` into `values[0]` (a tree over `levels = log2(units)` rounds), every
/// unit of the workgroup taking part; the sum is visible to all units on return.
#[cube]
pub(crate) fn tree_sum(values: &mut Shared<[f32]>, #[comptime] units: usize, #[comptime] levels: u32) {
    let u = UNIT_POS as usize;
    sync_cube();
    for level in 0..levels {
        let stride = units >> (level as usize + 1);
        if u < stride {
            let s = values[u] + values[u + stride];
            values[u] = s;
        }
        sync_cube();
    }
}

/// Elements each unit of a two-stage reduction's first stage sums, about.
const ELEMENTS_PER_UNIT: usize = 8;

/// Workgroups of [`REDUCE_UNITS`] units for the first stage of a two-stage sum over `len`
/// elements: about [`ELEMENTS_PER_UNIT`] per unit, at most [`REDUCE_UNITS`] (the second stage,
/// `sum_partials_kernel`, adds one partial per unit).
fn reduce_groups(len: usize) -> usize {
    len.div_ceil(REDUCE_UNITS * ELEMENTS_PER_UNIT).clamp(1, REDUCE_UNITS)
}

/// First stage of a two-stage sum: `partials[g]` the sum over workgroup `g`'s elements
/// (`i = (g · units + unit) + r · groups · units`, those below `len`) of `|x − y|`
/// (`abs_diff`) or of `x` (`y` unread).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn partial_sums_kernel(
    x: &Tensor<f32>,
    y: &Tensor<f32>,
    partials: &mut Tensor<f32>,
    len: u32,
    groups: u32,
    #[comptime] abs_diff: bool,
    #[comptime] units: usize,
    #[comptime] levels: u32,
) {
    let u = UNIT_POS as usize;
    let first = CUBE_POS * units + u;
    let stride = (groups as usize) * units;
    let mut sums = Shared::<[f32]>::new_slice(units);
    let mut a = 0.0f32;
    for r in 0..(len as usize).div_ceil(stride) {
        let i = first + r * stride;
        if i < len as usize {
            if abs_diff {
                a += f32::abs(x[i] - y[i]);
            } else {
                a += x[i];
            }
        }
    }
    sums[u] = a;
    tree_sum(&mut sums, units, levels);
    if u == 0 {
        partials[CUBE_POS] = sums[0];
    }
}

/// Second stage: `out[0] = scale · Σ partials[0..groups]` (`groups` ≤ `units`), one workgroup.
#[cube(launch)]
fn sum_partials_kernel(
    partials: &Tensor<f32>,
    out: &mut Tensor<f32>,
    groups: u32,
    scale: f32,
    #[comptime] units: usize,
    #[comptime] levels: u32,
) {
    let u = UNIT_POS as usize;
    let mut sums = Shared::<[f32]>::new_slice(units);
    let mut a = 0.0f32;
    if u < groups as usize {
        a = partials[u];
    }
    sums[u] = a;
    tree_sum(&mut sums, units, levels);
    if u == 0 {
        out[0] = sums[0] * scale;
    }
}

/// `[1]`: the mean of `|x − y|` (`y` given) or of `x` over all elements of `x` (same shape as
/// `y`, contiguous f32), in two launches: a sum per workgroup ([`reduce_groups`]), then theirs.
pub(crate) fn mean(x: &CubeTensor, y: Option<&CubeTensor>) -> CubeTensor {
    let len = x.shape().num_elements();
    let groups = reduce_groups(len);
    let partials = empty(vec![groups], x);
    partial_sums_kernel::launch(
        &x.client,
        CubeCount::Static(groups as u32, 1, 1),
        CubeDim::new_1d(REDUCE_UNITS as u32),
        x.clone().into_tensor_arg(),
        y.unwrap_or(x).clone().into_tensor_arg(),
        partials.clone().into_tensor_arg(),
        len as u32,
        groups as u32,
        y.is_some(),
        REDUCE_UNITS,
        REDUCE_LEVELS,
    );
    let out = empty(vec![1], x);
    sum_partials_kernel::launch(
        &x.client,
        CubeCount::Static(1, 1, 1),
        CubeDim::new_1d(REDUCE_UNITS as u32),
        partials.into_tensor_arg(),
        out.clone().into_tensor_arg(),
        groups as u32,
        1.0 / len.max(1) as f32,
        REDUCE_UNITS,
        REDUCE_LEVELS,
    );
    out
}
