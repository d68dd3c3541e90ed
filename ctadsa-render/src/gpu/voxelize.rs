//! CubeCL voxelisation kernel: one unit per Gaussian walks the voxels of its k-σ box and adds
//! the density at the voxel centres inside the ellipsoid (atomic adds; the volume is bound as
//! both of its typed arguments, see [`super::atomics`]).

use burn_cubecl::cubecl;
use cubecl::prelude::*;

use super::atomics::add_f32;
use super::math::{load_params, quat_to_mat, sandwich_diag};

/// `grid` = `[origin (3), spacing (3), dims (3)]` as f32.
#[cube(launch)]
pub fn voxelize_kernel(
    means: &Tensor<f32>,
    scales: &Tensor<f32>,
    rotations: &Tensor<f32>,
    densities: &Tensor<f32>,
    grid: &Tensor<f32>,
    volume_f32: &mut Tensor<Atomic<f32>>,
    volume_u32: &mut Tensor<Atomic<u32>>,
    n: u32,
    k_sigma: f32,
    #[comptime] native: bool,
) {
    let i = ABSOLUTE_POS;
    if i >= n as usize {
        terminate!();
    }
    let p = load_params(means, scales, rotations, densities, i);
    if p.valid == 1u32 {
        let r = quat_to_mat(p.qw, p.qx, p.qy, p.qz);
        let q = sandwich_diag(&r, 1.0 / (p.s0 * p.s0), 1.0 / (p.s1 * p.s1), 1.0 / (p.s2 * p.s2));
        let sig = sandwich_diag(&r, p.s0 * p.s0, p.s1 * p.s1, p.s2 * p.s2);
        let ox = grid[0];
        let oy = grid[1];
        let oz = grid[2];
        let hx = grid[3];
        let hy = grid[4];
        let hz = grid[5];
        let nx = grid[6];
        let ny = grid[7];
        let nz = grid[8];
        let x_lo = f32::max(f32::ceil((p.mx - k_sigma * f32::sqrt(sig.xx) - ox) / hx - 0.5), 0.0);
        let x_hi = f32::min(f32::floor((p.mx + k_sigma * f32::sqrt(sig.xx) - ox) / hx - 0.5), nx - 1.0);
        let y_lo = f32::max(f32::ceil((p.my - k_sigma * f32::sqrt(sig.yy) - oy) / hy - 0.5), 0.0);
        let y_hi = f32::min(f32::floor((p.my + k_sigma * f32::sqrt(sig.yy) - oy) / hy - 0.5), ny - 1.0);
        let z_lo = f32::max(f32::ceil((p.mz - k_sigma * f32::sqrt(sig.zz) - oz) / hz - 0.5), 0.0);
        let z_hi = f32::min(f32::floor((p.mz + k_sigma * f32::sqrt(sig.zz) - oz) / hz - 0.5), nz - 1.0);
        if x_lo <= x_hi && y_lo <= y_hi && z_lo <= z_hi {
            let k2 = k_sigma * k_sigma;
            let nyu = u32::cast_from(ny) as usize;
            let nzu = u32::cast_from(nz) as usize;
            for ix in u32::cast_from(x_lo)..u32::cast_from(x_hi) + 1 {
                let dx = ox + (f32::cast_from(ix) + 0.5) * hx - p.mx;
                for iy in u32::cast_from(y_lo)..u32::cast_from(y_hi) + 1 {
                    let dy = oy + (f32::cast_from(iy) + 0.5) * hy - p.my;
                    let base = ((ix as usize) * nyu + iy as usize) * nzu;
                    for iz in u32::cast_from(z_lo)..u32::cast_from(z_hi) + 1 {
                        let dz = oz + (f32::cast_from(iz) + 0.5) * hz - p.mz;
                        let m = q.xx * dx * dx
                            + q.yy * dy * dy
                            + q.zz * dz * dz
                            + 2.0 * (q.xy * dx * dy + q.xz * dx * dz + q.yz * dy * dz);
                        if m <= k2 {
                            add_f32(
                                volume_f32,
                                volume_u32,
                                base + iz as usize,
                                p.density * f32::exp(m * -0.5f32),
                                native,
                            );
                        }
                    }
                }
            }
        }
    }
}
