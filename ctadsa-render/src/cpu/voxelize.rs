//! CPU voxelisation: the density field `Σ ρ_i exp(−½ (x−μ_i)ᵀ Q_i (x−μ_i))` at voxel centres.
//!
//! The grid is split into slabs along `x` (contiguous in the `[X, Y, Z]` output), Gaussians are
//! binned to the slabs their k-σ box touches, and slabs are filled in parallel.

use rayon::prelude::*;

use super::host::HostGaussians;
use super::math::{clamp_scales, exp_neg, quat_to_mat, sandwich_diag};
use crate::VoxelGrid;

/// Slab thickness along `x` in voxels.
const SLAB: usize = 4;

/// One Gaussian ready for voxel evaluation.
#[derive(Debug, Clone, Copy)]
struct Prepared {
    mean: [f32; 3],
    q: [f32; 6],
    density: f32,
    lo: [usize; 3],
    hi: [usize; 3],
}

fn prepare(g: &HostGaussians, i: usize, grid: &VoxelGrid, k_sigma: f32) -> Option<Prepared> {
    let (mean, scale, quat, density) = g.get(i);
    if !(density.is_finite() && mean.iter().all(|v| v.is_finite())) {
        return None;
    }
    let (s, _) = clamp_scales(scale)?;
    let (r, _, _) = quat_to_mat(quat)?;
    let q = sandwich_diag(&r, s.map(|v| 1.0 / (v * v)));
    let sig = sandwich_diag(&r, s.map(|v| v * v));
    let half = [sig[0], sig[3], sig[5]].map(|v| k_sigma * v.sqrt());
    let mut lo = [0usize; 3];
    let mut hi = [0usize; 3];
    for a in 0..3 {
        let h = grid.spacing_mm[a];
        let first = ((mean[a] - half[a] - grid.origin_mm[a]) / h - 0.5).ceil();
        let last = ((mean[a] + half[a] - grid.origin_mm[a]) / h - 0.5).floor();
        let last = last.min(grid.dims[a] as f32 - 1.0);
        let first = first.max(0.0);
        if !(first <= last) {
            return None;
        }
        lo[a] = first as usize;
        hi[a] = last as usize;
    }
    Some(Prepared { mean, q, density, lo, hi })
}

/// Evaluates the density field on `grid`; output `[X, Y, Z]` row-major (`z` fastest).
pub fn voxelize(g: &HostGaussians, grid: &VoxelGrid, k_sigma: f32) -> Vec<f32> {
    let [nx, ny, nz] = grid.dims.map(|d| d as usize);
    let mut out = vec![0.0f32; nx * ny * nz];
    if out.is_empty() {
        return out;
    }
    let prepared: Vec<Option<Prepared>> =
        (0..g.len()).into_par_iter().with_min_len(1024).map(|i| prepare(g, i, grid, k_sigma)).collect();
    let n_slabs = nx.div_ceil(SLAB);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); n_slabs];
    for (i, p) in prepared.iter().enumerate() {
        if let Some(p) = p {
            for bin in &mut bins[p.lo[0] / SLAB..=p.hi[0] / SLAB] {
                bin.push(i as u32);
            }
        }
    }
    out.par_chunks_mut(SLAB * ny * nz)
        .zip(bins.par_iter())
        .enumerate()
        .for_each(|(slab, (chunk, ids))| splat_slab(&prepared, ids, grid, k_sigma, slab * SLAB, chunk));
    out
}

/// Adds the Gaussians `ids` to the slab of x-planes from `x_first` (`chunk`, `[SLAB, Y, Z]`).
#[multiversion::multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn splat_slab(
    prepared: &[Option<Prepared>],
    ids: &[u32],
    grid: &VoxelGrid,
    k_sigma: f32,
    x_first: usize,
    chunk: &mut [f32],
) {
    let [nx, ny, nz] = grid.dims.map(|d| d as usize);
    let k2 = k_sigma * k_sigma;
    for &id in ids {
        let Some(p) = &prepared[id as usize] else { continue };
        let q = &p.q;
        let x_lo = p.lo[0].max(x_first);
        let x_hi = p.hi[0].min(x_first + SLAB - 1).min(nx - 1);
        for ix in x_lo..=x_hi {
            let dx = grid.origin_mm[0] + (ix as f32 + 0.5) * grid.spacing_mm[0] - p.mean[0];
            for iy in p.lo[1]..=p.hi[1] {
                let dy = grid.origin_mm[1] + (iy as f32 + 0.5) * grid.spacing_mm[1] - p.mean[1];
                let base = ((ix - x_first) * ny + iy) * nz;
                let row = &mut chunk[base + p.lo[2]..=base + p.hi[2]];
                for (j, v) in row.iter_mut().enumerate() {
                    let dz = grid.origin_mm[2] + ((p.lo[2] + j) as f32 + 0.5) * grid.spacing_mm[2] - p.mean[2];
                    let m = q[0] * dx * dx
                        + q[3] * dy * dy
                        + q[5] * dz * dz
                        + 2.0 * (q[1] * dx * dy + q[2] * dx * dz + q[4] * dy * dz);
                    if m <= k2 {
                        *v += p.density * exp_neg(-0.5 * m);
                    }
                }
            }
        }
    }
}
