//! Voxel volumes in world millimetres: label volumes, density volumes, and their I/O.

pub mod edt;
pub mod nifti_io;
pub mod rasterize;
pub mod skeleton;

use glam::{DMat4, DVec3, DVec4};
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};

/// An axis-aligned box (mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BoxMm {
    pub min_mm: [f64; 3],
    pub max_mm: [f64; 3],
}

impl BoxMm {
    /// Size along each axis (mm).
    pub fn size_mm(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| self.max_mm[a] - self.min_mm[a])
    }

    /// The box grown by `margin_mm` on every side.
    pub fn padded(&self, margin_mm: f64) -> Self {
        Self { min_mm: self.min_mm.map(|v| v - margin_mm), max_mm: self.max_mm.map(|v| v + margin_mm) }
    }

    /// Whether `p` is inside (boundary included).
    pub fn contains(&self, p: DVec3) -> bool {
        (0..3).all(|a| p[a] >= self.min_mm[a] && p[a] <= self.max_mm[a])
    }
}

/// A regular axis-aligned grid: voxel `(i, j, k)` has its centre at
/// `origin_mm + ((i, j, k) + ½)·spacing_mm` (`origin_mm` is the outer corner of voxel 0).
/// Arrays on it are `[X, Y, Z]` with `z` fastest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    pub origin_mm: [f64; 3],
}

/// The most voxels a grid may have (2^29: 2 GiB as `f32`); larger grids come from input sizes
/// or voxel sizes that are off by orders of magnitude.
pub const MAX_GRID_VOXELS: usize = 1 << 29;

impl Grid {
    /// Marks in `reached` every voxel that a 26-connected path of `passable` voxels links to
    /// one in `stack` (which must be marked already); `reached` is `[len]`, indices as
    /// [`Grid::index`].
    pub fn flood_fill_26(&self, reached: &mut [bool], mut stack: Vec<usize>, passable: impl Fn(usize) -> bool) {
        let [nx, ny, nz] = self.dims;
        while let Some(i) = stack.pop() {
            let (x, y, z) = (i / (ny * nz), (i / nz) % ny, i % nz);
            for a in x.saturating_sub(1)..(x + 2).min(nx) {
                for b in y.saturating_sub(1)..(y + 2).min(ny) {
                    for c in z.saturating_sub(1)..(z + 2).min(nz) {
                        let j = self.index(a, b, c);
                        if !reached[j] && passable(j) {
                            reached[j] = true;
                            stack.push(j);
                        }
                    }
                }
            }
        }
    }

    /// A grid of isotropic `voxel_mm` voxels covering `bounds` (rounded up to whole voxels,
    /// centred on the box).
    pub fn covering(bounds: &BoxMm, voxel_mm: f64) -> Result<Self> {
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(CoreError::invalid(format!("voxel size must be positive, got {voxel_mm} mm")));
        }
        let size = bounds.size_mm();
        if !size.iter().all(|s| s.is_finite() && *s >= 0.0) {
            return Err(CoreError::invalid(format!("degenerate box {bounds:?}")));
        }
        let dims_f = size.map(|s| (s / voxel_mm).ceil().max(1.0));
        let total = dims_f.iter().product::<f64>();
        if total > MAX_GRID_VOXELS as f64 {
            let n = |x: f64| if x < 1e7 { format!("{x:.0}") } else { format!("{x:.2e}") };
            let mm = |x: f64| if x < 1e6 { format!("{x:.1}") } else { format!("{x:.2e}") };
            return Err(CoreError::invalid(format!(
                "a grid of {} × {} × {} voxels ({total:.2e}) would cover {} × {} × {} mm at {voxel_mm} mm \
                 (at most {MAX_GRID_VOXELS}): raise the voxel size",
                n(dims_f[0]),
                n(dims_f[1]),
                n(dims_f[2]),
                mm(size[0]),
                mm(size[1]),
                mm(size[2])
            )));
        }
        let dims = dims_f.map(|d| d as usize);
        let origin_mm = [0, 1, 2].map(|a| {
            let centre = 0.5 * (bounds.min_mm[a] + bounds.max_mm[a]);
            centre - 0.5 * dims[a] as f64 * voxel_mm
        });
        Ok(Self { dims, spacing_mm: [voxel_mm; 3], origin_mm })
    }

    /// A grid of `n` voxels along the longest side of `bounds` (cubic voxels).
    pub fn with_longest_side(bounds: &BoxMm, n: usize) -> Result<Self> {
        let longest = bounds.size_mm().into_iter().fold(0.0f64, f64::max);
        if n == 0 || longest <= 0.0 {
            return Err(CoreError::invalid(format!("cannot put {n} voxels on a box of size {longest} mm")));
        }
        Self::covering(bounds, longest / n as f64)
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    /// Whether the grid has no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of `(i, j, k)`.
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    /// Linear index of the voxel containing `p` (mm); `None` outside the grid.
    #[inline]
    pub fn index_at(&self, p: DVec3) -> Option<usize> {
        let ijk = [0, 1, 2].map(|a| ((p[a] - self.origin_mm[a]) / self.spacing_mm[a]).floor());
        ijk.iter()
            .zip(self.dims)
            .all(|(&v, d)| v >= 0.0 && v < d as f64)
            .then(|| self.index(ijk[0] as usize, ijk[1] as usize, ijk[2] as usize))
    }

    /// Centre of voxel `(i, j, k)` (mm).
    #[inline]
    pub fn centre_mm(&self, i: usize, j: usize, k: usize) -> DVec3 {
        DVec3::new(
            self.origin_mm[0] + (i as f64 + 0.5) * self.spacing_mm[0],
            self.origin_mm[1] + (j as f64 + 0.5) * self.spacing_mm[1],
            self.origin_mm[2] + (k as f64 + 0.5) * self.spacing_mm[2],
        )
    }

    /// The box the grid covers.
    pub fn bounds(&self) -> BoxMm {
        BoxMm {
            min_mm: self.origin_mm,
            max_mm: [0, 1, 2].map(|a| self.origin_mm[a] + self.dims[a] as f64 * self.spacing_mm[a]),
        }
    }

    /// Matrix from voxel index (of the voxel centre) to world mm.
    pub fn index_to_world(&self) -> DMat4 {
        let s = self.spacing_mm;
        DMat4::from_cols(
            DVec4::new(s[0], 0.0, 0.0, 0.0),
            DVec4::new(0.0, s[1], 0.0, 0.0),
            DVec4::new(0.0, 0.0, s[2], 0.0),
            DVec4::new(
                self.origin_mm[0] + 0.5 * s[0],
                self.origin_mm[1] + 0.5 * s[1],
                self.origin_mm[2] + 0.5 * s[2],
                1.0,
            ),
        )
    }

    /// The same grid for the renderer (f32).
    pub fn to_render_grid(&self) -> Result<ctadsa_render::VoxelGrid> {
        Ok(ctadsa_render::VoxelGrid {
            origin_mm: self.origin_mm.map(|v| v as f32),
            spacing_mm: self.spacing_mm.map(|v| v as f32),
            dims: [0, 1, 2].map(|a| self.dims[a] as u32),
        })
    }
}

/// A volume of voxel values on a [`Grid`], with the voxel-index → world matrix it came with
/// (for grids we make, [`Grid::index_to_world`]; for NIfTI files, the file's affine).
#[derive(Debug, Clone, PartialEq)]
pub struct Volume<T> {
    pub grid: Grid,
    /// Voxel (centre) index → world mm. May include rotations/flips for volumes read from files.
    pub index_to_world: DMat4,
    /// Values, `[X, Y, Z]`, `z` fastest.
    pub data: Vec<T>,
}

impl<T: Copy + Default> Volume<T> {
    /// A volume of default values on `grid`.
    pub fn zeros(grid: Grid) -> Self {
        Self { grid, index_to_world: grid.index_to_world(), data: vec![T::default(); grid.len()] }
    }

    /// Value at `(i, j, k)`.
    #[inline]
    pub fn get(&self, i: usize, j: usize, k: usize) -> T {
        self.data[self.grid.index(i, j, k)]
    }

    /// Maps every value.
    pub fn map<U>(&self, f: impl Fn(T) -> U) -> Volume<U> {
        Volume { grid: self.grid, index_to_world: self.index_to_world, data: self.data.iter().map(|&v| f(v)).collect() }
    }
}

impl Volume<f32> {
    /// The value at `p` (mm), trilinear between voxel centres; 0 where a corner lies outside
    /// the grid.
    pub fn trilinear_at(&self, p: DVec3) -> f64 {
        let g = &self.grid;
        let f = [0, 1, 2].map(|a| (p[a] - g.origin_mm[a]) / g.spacing_mm[a] - 0.5);
        let base = f.map(f64::floor);
        let mut sum = 0.0;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut ijk = [0usize; 3];
            for a in 0..3 {
                let up = (corner >> a) & 1 == 1;
                let i = base[a] as i64 + i64::from(up);
                if i < 0 || i >= g.dims[a] as i64 {
                    return 0.0;
                }
                ijk[a] = i as usize;
                let t = f[a] - base[a];
                w *= if up { t } else { 1.0 - t };
            }
            sum += w * f64::from(self.get(ijk[0], ijk[1], ijk[2]));
        }
        sum
    }
}

impl Volume<u8> {
    /// Whether the voxel containing `p` (mm) is set; false outside the grid.
    pub fn is_set_at(&self, p: DVec3) -> bool {
        self.grid.index_at(p).is_some_and(|i| self.data[i] != 0)
    }

    /// Number of non-zero voxels.
    pub fn count_nonzero(&self) -> usize {
        self.data.iter().filter(|&&v| v != 0).count()
    }
}

#[cfg(test)]
mod trilinear_tests {
    use super::*;

    /// A field linear in x, y, z is reproduced exactly between voxel centres; beyond the outer
    /// centres (a corner outside the grid) the value is 0.
    #[test]
    fn trilinear_reproduces_a_linear_field_and_is_zero_outside() {
        let grid = Grid::covering(&BoxMm { min_mm: [-2.0; 3], max_mm: [2.0; 3] }, 0.5).unwrap();
        let linear = |p: DVec3| 2.0 * p.x + 3.0 * p.y - p.z + 1.0;
        let mut v = Volume::<f32>::zeros(grid);
        for i in 0..grid.dims[0] {
            for j in 0..grid.dims[1] {
                for k in 0..grid.dims[2] {
                    v.data[grid.index(i, j, k)] = linear(grid.centre_mm(i, j, k)) as f32;
                }
            }
        }
        for p in [DVec3::new(0.1, -0.37, 0.9), DVec3::new(-1.2, 1.1, 0.05), DVec3::ZERO] {
            assert!((v.trilinear_at(p) - linear(p)).abs() < 1e-5, "{p}: {} vs {}", v.trilinear_at(p), linear(p));
        }
        assert_eq!(v.trilinear_at(DVec3::new(1.9, 0.0, 0.0)), 0.0);
        assert_eq!(v.trilinear_at(DVec3::new(0.0, 0.0, -5.0)), 0.0);
    }
}
