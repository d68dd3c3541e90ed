//! Regular voxel grids in world millimetres.

use crate::RenderError;

/// An axis-aligned voxel grid: voxel `(i, j, k)` has its centre at
/// `origin_mm + ((i, j, k) + ½) · spacing_mm`. Volumes on it are `[X, Y, Z]`, `z` fastest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelGrid {
    /// The corner of voxel (0, 0, 0) with the smallest coordinates (mm, world).
    pub origin_mm: [f32; 3],
    /// Voxel edge lengths (mm).
    pub spacing_mm: [f32; 3],
    /// Number of voxels along x, y, z.
    pub dims: [u32; 3],
}

impl VoxelGrid {
    /// A grid of `dims` voxels spanning the box `[min_mm, max_mm]`.
    pub fn from_bounds(min_mm: [f32; 3], max_mm: [f32; 3], dims: [u32; 3]) -> Result<Self, RenderError> {
        let spacing_mm = [0, 1, 2].map(|a| (max_mm[a] - min_mm[a]) / dims[a].max(1) as f32);
        let g = Self { origin_mm: min_mm, spacing_mm, dims };
        g.validate()?;
        Ok(g)
    }

    /// A grid of `dims` voxels of `spacing_mm` centred on the world origin.
    pub fn centred(spacing_mm: [f32; 3], dims: [u32; 3]) -> Result<Self, RenderError> {
        let origin_mm = [0, 1, 2].map(|a| -0.5 * spacing_mm[a] * dims[a] as f32);
        let g = Self { origin_mm, spacing_mm, dims };
        g.validate()?;
        Ok(g)
    }

    /// Checks that spacings are positive and finite, the origin finite and no axis is empty.
    pub fn validate(&self) -> Result<(), RenderError> {
        if self.dims.contains(&0) {
            return Err(RenderError::InvalidGrid(format!("empty axis in dims {:?}", self.dims)));
        }
        if !self.spacing_mm.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(RenderError::InvalidGrid(format!(
                "spacing must be positive and finite, got {:?} mm",
                self.spacing_mm
            )));
        }
        if !self.origin_mm.iter().all(|o| o.is_finite()) {
            return Err(RenderError::InvalidGrid(format!("non-finite origin {:?}", self.origin_mm)));
        }
        Ok(())
    }

    /// Centre of voxel `(i, j, k)` (mm).
    pub fn voxel_centre_mm(&self, index: [u32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|a| self.origin_mm[a] + (index[a] as f32 + 0.5) * self.spacing_mm[a])
    }

    /// The box the grid covers: `(min, max)` corners (mm).
    pub fn bounds_mm(&self) -> ([f32; 3], [f32; 3]) {
        (self.origin_mm, [0, 1, 2].map(|a| self.origin_mm[a] + self.spacing_mm[a] * self.dims[a] as f32))
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// Whether the grid has no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
