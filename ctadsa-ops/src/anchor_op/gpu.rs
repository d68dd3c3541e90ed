//! The anchor search on CubeCL: one unit per query walks the shells of cells around it
//! (`grid.rs` says how; this kernel follows it step for step, skipping the same cells, with the
//! k nearest kept sorted in local arrays of [`MAX_K`] entries).

use burn::backend::ops::IntTensorOps;
use burn::backend::{IntDType, TensorMetadata};
use burn::tensor::Shape;
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::kernel::into_contiguous;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use super::grid::{MAX_K, MAX_SHELL, SLOT};
use super::{AnchorSearch, AnchorTargets};
use crate::cube::{empty, launch_1d, prepare};

/// `(first point, count)` of cell `(cx, cy, cz)`; count 0 when the cell is empty.
#[cube]
fn lookup(table: &Tensor<f32>, cx: u32, cy: u32, cz: u32, mask: u32) -> (u32, u32) {
    let mut s = ((cx * 73_856_093u32) ^ (cy * 19_349_663u32) ^ (cz * 83_492_791u32)) & mask;
    let mut start = 0u32;
    let mut count = 0u32;
    let (fx, fy, fz) = (f32::cast_from(cx), f32::cast_from(cy), f32::cast_from(cz));
    loop {
        let base = (s as usize) * 5usize;
        let kx = table[base];
        if kx < 0.0f32 {
            break;
        }
        if kx == fx && table[base + 1] == fy && table[base + 2] == fz {
            start = u32::cast_from(table[base + 3]);
            count = u32::cast_from(table[base + 4]);
            break;
        }
        s = (s + 1u32) & mask;
    }
    (start, count)
}

#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn anchor_kernel(
    queries: &Tensor<f32>,
    sample: &Tensor<i32>,
    chosen: &mut Tensor<f32>,
    points: &Tensor<f32>,
    table: &Tensor<f32>,
    targets: &mut Tensor<f32>,
    keep: &mut Tensor<f32>,
    m: u32,
    origin_x: f32,
    origin_y: f32,
    origin_z: f32,
    cell: f32,
    mask: u32,
    k: u32,
    radius: f32,
    max_shell: u32,
    #[comptime] max_k: usize,
    #[comptime] gathered: bool,
) {
    let i = ABSOLUTE_POS;
    if i >= m as usize {
        terminate!();
    }
    // Query `i` is row `sample[i]` of `queries` when gathered (and copied to `chosen`).
    let mut q = i;
    if gathered {
        q = sample[i] as usize;
    }
    let qx = queries[3 * q];
    let qy = queries[3 * q + 1];
    let qz = queries[3 * q + 2];
    if gathered {
        chosen[3 * i] = qx;
        chosen[3 * i + 1] = qy;
        chosen[3 * i + 2] = qz;
    }
    let cx = i32::cast_from(f32::floor((qx - origin_x) / cell));
    let cy = i32::cast_from(f32::floor((qy - origin_y) / cell));
    let cz = i32::cast_from(f32::floor((qz - origin_z) / cell));
    let mut best_d = Array::<f32>::new(max_k);
    let mut best_p = Array::<u32>::new(max_k);
    for j in 0..max_k {
        best_d[j] = 3.0e38f32;
        best_p[j] = 0u32;
    }
    let mut found = 0u32;
    let r2 = radius * radius;
    let mut s = 0i32;
    loop {
        let side = 2 * s + 1;
        for dz in 0..side {
            for dy in 0..side {
                for dx in 0..side {
                    let ox = dx - s;
                    let oy = dy - s;
                    let oz = dz - s;
                    let shell = i32::max(i32::max(i32::abs(ox), i32::abs(oy)), i32::abs(oz));
                    let x = cx + ox;
                    let y = cy + oy;
                    let z = cz + oz;
                    // A cell whose box lies beyond the k-th nearest so far is skipped (as on
                    // the CPU, with the same slack for the binning's rounding).
                    let mut near = true;
                    if found >= k {
                        let slack = 1.0e-4f32 * cell;
                        let lx = origin_x + f32::cast_from(x) * cell;
                        let ly = origin_y + f32::cast_from(y) * cell;
                        let lz = origin_z + f32::cast_from(z) * cell;
                        let bx = f32::max(f32::max(lx - qx, qx - (lx + cell)) - slack, 0.0f32);
                        let by = f32::max(f32::max(ly - qy, qy - (ly + cell)) - slack, 0.0f32);
                        let bz = f32::max(f32::max(lz - qz, qz - (lz + cell)) - slack, 0.0f32);
                        near = bx * bx + by * by + bz * bz <= best_d[(k - 1u32) as usize];
                    }
                    if shell == s && x >= 0 && y >= 0 && z >= 0 && near {
                        let (start, count) =
                            lookup(table, u32::cast_from(x), u32::cast_from(y), u32::cast_from(z), mask);
                        for p in start..start + count {
                            let pi = p as usize;
                            let ddx = points[3 * pi] - qx;
                            let ddy = points[3 * pi + 1] - qy;
                            let ddz = points[3 * pi + 2] - qz;
                            let d2 = ddx * ddx + ddy * ddy + ddz * ddz;
                            // Insert into the sorted k best (ties: the earlier point first).
                            let last = (k - 1u32) as usize;
                            if d2 < best_d[last] {
                                let mut at = last;
                                while at > 0usize && best_d[at - 1] > d2 {
                                    best_d[at] = best_d[at - 1];
                                    best_p[at] = best_p[at - 1];
                                    at -= 1;
                                }
                                best_d[at] = d2;
                                best_p[at] = p;
                                if found < k {
                                    found += 1u32;
                                }
                            }
                        }
                    }
                }
            }
        }
        let bound = f32::cast_from(s) * cell;
        let last = (k - 1u32) as usize;
        if found >= k && best_d[last] <= bound * bound {
            break;
        }
        if bound >= radius && (found == 0u32 || best_d[0] > r2) {
            break;
        }
        if s >= max_shell as i32 {
            break;
        }
        s += 1;
    }
    let kept = found > 0u32 && best_d[0] <= r2;
    let mut mx = qx;
    let mut my = qy;
    let mut mz = qz;
    if kept {
        let mut sx = 0.0f32;
        let mut sy = 0.0f32;
        let mut sz = 0.0f32;
        for j in 0..found {
            let pi = best_p[j as usize] as usize;
            sx += points[3 * pi];
            sy += points[3 * pi + 1];
            sz += points[3 * pi + 2];
        }
        let n = f32::cast_from(found);
        mx = sx / n;
        my = sy / n;
        mz = sz / n;
    }
    targets[3 * i] = mx;
    targets[3 * i + 1] = my;
    targets[3 * i + 2] = mz;
    keep[i] = select(kept, 1.0f32, 0.0f32);
}

/// The anchor targets of `queries` `[m, 3]` on the GPU.
pub fn anchor_targets(
    queries: CubeTensor,
    points: CubeTensor,
    table: CubeTensor,
    search: AnchorSearch,
) -> AnchorTargets<CubeBackend> {
    let m = queries.shape()[0];
    search_kernel(queries, None, m, points, table, search).1
}

/// The rows `means[sample]` `[m, 3]` and their anchor targets, the gather done by the search.
pub fn gathered_anchor_targets(
    means: CubeTensor,
    sample: CubeTensor,
    points: CubeTensor,
    table: CubeTensor,
    search: AnchorSearch,
) -> (CubeTensor, AnchorTargets<CubeBackend>) {
    let sample = CubeBackend::int_cast(sample, IntDType::I32);
    let m = sample.shape()[0];
    search_kernel(means, Some(sample), m, points, table, search)
}

/// One launch of [`anchor_kernel`] for `m` queries: the rows of `queries`, or the rows
/// `sample` names (then also copied into the first tensor returned; a placeholder otherwise).
fn search_kernel(
    queries: CubeTensor,
    sample: Option<CubeTensor>,
    m: usize,
    points: CubeTensor,
    table: CubeTensor,
    search: AnchorSearch,
) -> (CubeTensor, AnchorTargets<CubeBackend>) {
    let (queries, points, table) = (prepare(queries), prepare(points), prepare(table));
    let targets = empty(vec![m, 3], &queries);
    let keep = empty(vec![m], &queries);
    let gathered = sample.is_some();
    let chosen = empty(if gathered { vec![m, 3] } else { vec![1] }, &queries);
    let sample = match sample {
        Some(s) => into_contiguous(s),
        None => CubeBackend::int_empty(Shape::new([1]), &queries.device, IntDType::I32),
    };
    let slots = table.shape().num_elements() / SLOT;
    if m > 0 && slots > 0 {
        let (count, dim) = launch_1d(&queries, m, 64);
        anchor_kernel::launch(
            &queries.client,
            count,
            dim,
            queries.clone().into_tensor_arg(),
            sample.into_tensor_arg(),
            chosen.clone().into_tensor_arg(),
            points.into_tensor_arg(),
            table.into_tensor_arg(),
            targets.clone().into_tensor_arg(),
            keep.clone().into_tensor_arg(),
            m as u32,
            search.origin[0],
            search.origin[1],
            search.origin[2],
            search.cell_mm,
            (slots - 1) as u32,
            search.k.clamp(1, MAX_K) as u32,
            search.radius_mm,
            MAX_SHELL,
            MAX_K,
            gathered,
        );
    }
    (chosen, AnchorTargets { targets, keep })
}
