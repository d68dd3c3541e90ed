//! CubeCL kernels of the hash encoding, one unit per (point, level), mirroring `cpu.rs`.
//! The backward writes per-level position gradients (summed afterwards) and adds the table
//! gradients atomically: with the device's f32 add where it has one, else a compare-and-swap
//! loop (`ctadsa_render::kernels`).

use burn::backend::ops::FloatTensorOps;
use burn::backend::{FloatDType, TensorMetadata};
use burn::tensor::{Shape, TensorData};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use ctadsa_render::kernels::{Accumulator, add_f32};

use crate::cube::{empty, launch_1d, prepare};

use super::config::{HASH_P1, HASH_P2, HashGridConfig};

/// `meta` per level: `[resolution, r + 1, dense (0/1), base row]`.
#[cube]
fn corner(u: &Tensor<f32>, meta: &Tensor<f32>, i: usize, l: usize, k: u32, mask: u32) -> (u32, f32, f32, f32, f32) {
    corner_at(u[3 * i], u[3 * i + 1], u[3 * i + 2], meta, l, k, mask)
}

/// Corner `k` of level `l` around the point `(ux, uy, uz)`: its parameter row (without the
/// feature offset), its trilinear weight and that weight's derivatives with respect to `u`.
#[cube]
pub(crate) fn corner_at(
    ux: f32,
    uy: f32,
    uz: f32,
    meta: &Tensor<f32>,
    l: usize,
    k: u32,
    mask: u32,
) -> (u32, f32, f32, f32, f32) {
    let res = meta[4 * l];
    let r1 = u32::cast_from(meta[4 * l + 1]);
    let dense = meta[4 * l + 2];
    let base = u32::cast_from(meta[4 * l + 3]);
    let ox = k & 1u32;
    let oy = (k >> 1u32) & 1u32;
    let oz = (k >> 2u32) & 1u32;
    let cxf = f32::clamp(ux, 0.0, 0.999999);
    let cyf = f32::clamp(uy, 0.0, 0.999999);
    let czf = f32::clamp(uz, 0.0, 0.999999);
    let in_x = select(cxf == ux, 1.0f32, 0.0f32);
    let in_y = select(cyf == uy, 1.0f32, 0.0f32);
    let in_z = select(czf == uz, 1.0f32, 0.0f32);
    let px = cxf * res;
    let py = cyf * res;
    let pz = czf * res;
    let fx = f32::floor(px);
    let fy = f32::floor(py);
    let fz = f32::floor(pz);
    let cx = u32::cast_from(fx) + ox;
    let cy = u32::cast_from(fy) + oy;
    let cz = u32::cast_from(fz) + oz;
    let mut idx = (cx ^ (cy * (HASH_P1 as u32)) ^ (cz * (HASH_P2 as u32))) & mask;
    if dense > 0.5 {
        idx = cx + cy * r1 + cz * r1 * r1;
    }
    let ax = select(ox == 1u32, px - fx, 1.0 - (px - fx));
    let ay = select(oy == 1u32, py - fy, 1.0 - (py - fy));
    let az = select(oz == 1u32, pz - fz, 1.0 - (pz - fz));
    let sx = select(ox == 1u32, 1.0f32, -1.0f32);
    let sy = select(oy == 1u32, 1.0f32, -1.0f32);
    let sz = select(oz == 1u32, 1.0f32, -1.0f32);
    (base + idx, ax * ay * az, sx * ay * az * res * in_x, ax * sy * az * res * in_y, ax * ay * sz * res * in_z)
}

#[cube(launch)]
fn hash_forward_kernel(
    u: &Tensor<f32>,
    tables: &Tensor<f32>,
    meta: &Tensor<f32>,
    out: &mut Tensor<f32>,
    n: u32,
    levels: u32,
    features: u32,
    stride: u32,
    mask: u32,
) {
    let id = ABSOLUTE_POS;
    if id >= (n * levels) as usize {
        terminate!();
    }
    let i = id / (levels as usize);
    let l = id % (levels as usize);
    for f in 0..features {
        let mut acc = 0.0f32;
        for k in 0..8u32 {
            let (row, w, _a, _b, _c) = corner(u, meta, i, l, k, mask);
            acc += w * tables[(f * stride + row) as usize];
        }
        out[(i * (levels as usize) + l) * (features as usize) + f as usize] = acc;
    }
}

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn hash_backward_kernel(
    u: &Tensor<f32>,
    tables: &Tensor<f32>,
    meta: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_u_levels: &mut Tensor<f32>,
    grad_tables_f32: &mut Tensor<Atomic<f32>>,
    grad_tables_u32: &mut Tensor<Atomic<u32>>,
    n: u32,
    levels: u32,
    features: u32,
    stride: u32,
    mask: u32,
    #[comptime] native: bool,
) {
    let id = ABSOLUTE_POS;
    if id >= (n * levels) as usize {
        terminate!();
    }
    let i = id / (levels as usize);
    let l = id % (levels as usize);
    let mut gx = 0.0f32;
    let mut gy = 0.0f32;
    let mut gz = 0.0f32;
    for f in 0..features {
        let g = grad[(i * (levels as usize) + l) * (features as usize) + f as usize];
        for k in 0..8u32 {
            let (row, w, dx, dy, dz) = corner(u, meta, i, l, k, mask);
            let t = tables[(f * stride + row) as usize];
            gx += dx * g * t;
            gy += dy * g * t;
            gz += dz * g * t;
            add_f32(grad_tables_f32, grad_tables_u32, (f * stride + row) as usize, w * g, native);
        }
    }
    grad_u_levels[3 * id] = gx;
    grad_u_levels[3 * id + 1] = gy;
    grad_u_levels[3 * id + 2] = gz;
}

/// The per-level table of [`corner_at`] (`[levels, 4]`).
pub(crate) fn meta(c: &HashGridConfig, like: &CubeTensor) -> CubeTensor {
    let data: Vec<f32> = (0..c.levels)
        .flat_map(|l| {
            [c.resolution(l) as f32, (c.resolution(l) + 1) as f32, c.dense(l) as u8 as f32, c.level_offset(l) as f32]
        })
        .collect();
    CubeBackend::float_from_data(TensorData::new(data, [c.levels, 4]), &like.device)
}

fn dims(c: &HashGridConfig, n: usize, like: &CubeTensor) -> (CubeCount, CubeDim) {
    launch_1d(like, n * c.levels, 64)
}

/// Forward on the GPU: `[N, L·F]`.
pub fn encode(u: CubeTensor, tables: CubeTensor, c: &HashGridConfig) -> CubeTensor {
    let (u, tables) = (prepare(u), prepare(tables));
    let n = u.shape()[0];
    // Written whole by the kernel.
    let out = empty(vec![n, c.output_dim()], &u);
    if n == 0 {
        return out;
    }
    let meta = meta(c, &u);
    let (count, dim) = dims(c, n, &u);
    hash_forward_kernel::launch(
        &u.client,
        count,
        dim,
        u.clone().into_tensor_arg(),
        tables.into_tensor_arg(),
        meta.into_tensor_arg(),
        out.clone().into_tensor_arg(),
        n as u32,
        c.levels as u32,
        c.features as u32,
        c.rows() as u32,
        (c.table_size() - 1) as u32,
    );
    out
}

/// Backward on the GPU: `(∂L/∂u [N, 3], ∂L/∂tables [F, R])`.
pub fn encode_backward(
    u: CubeTensor,
    tables: CubeTensor,
    grad: CubeTensor,
    c: &HashGridConfig,
) -> (CubeTensor, CubeTensor) {
    let (u, tables, grad) = (prepare(u), prepare(tables), prepare(grad));
    let n = u.shape()[0];
    let grad_tables = CubeBackend::float_zeros(tables.shape(), &u.device, FloatDType::F32);
    // Written whole by the kernel (one unit per point and level).
    let per_level = empty(vec![n, c.levels, 3], &u);
    if n > 0 {
        let meta = meta(c, &u);
        let (count, dim) = dims(c, n, &u);
        let acc = Accumulator::new(&grad_tables, c.f32_add);
        hash_backward_kernel::launch(
            &u.client,
            count,
            dim,
            u.clone().into_tensor_arg(),
            tables.into_tensor_arg(),
            meta.into_tensor_arg(),
            grad.into_tensor_arg(),
            per_level.clone().into_tensor_arg(),
            acc.as_f32.into_tensor_arg(),
            acc.as_u32.into_tensor_arg(),
            n as u32,
            c.levels as u32,
            c.features as u32,
            c.rows() as u32,
            (c.table_size() - 1) as u32,
            acc.native,
        );
    }
    let grad_u = CubeBackend::float_reshape(CubeBackend::float_sum_dim(per_level, 1), Shape::from(vec![n, 3]));
    (grad_u, grad_tables)
}
