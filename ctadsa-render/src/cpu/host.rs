//! Host-side (CPU memory) views of the Gaussian parameters the CPU kernels read.

/// Borrowed Gaussian parameters, row-major: `means [N·3]` (mm, world), `scales [N·3]` (mm),
/// `rotations [N·4]` (quaternion `w, x, y, z`, any norm) and `densities [N]`.
#[derive(Debug, Clone, Copy)]
pub struct HostGaussians<'a> {
    pub means: &'a [f32],
    pub scales: &'a [f32],
    pub rotations: &'a [f32],
    pub densities: &'a [f32],
}

impl HostGaussians<'_> {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.densities.len()
    }

    /// Whether there are no Gaussians.
    #[cfg_attr(not(feature = "internals"), allow(dead_code))]
    pub fn is_empty(&self) -> bool {
        self.densities.is_empty()
    }

    /// Parameters of Gaussian `i`: `(mean, scale, quaternion, density)`.
    #[inline]
    pub fn get(&self, i: usize) -> ([f32; 3], [f32; 3], [f32; 4], f32) {
        let m = &self.means[3 * i..3 * i + 3];
        let s = &self.scales[3 * i..3 * i + 3];
        let q = &self.rotations[4 * i..4 * i + 4];
        ([m[0], m[1], m[2]], [s[0], s[1], s[2]], [q[0], q[1], q[2], q[3]], self.densities[i])
    }
}
