//! What the outputs read of a run: the Gaussians on the host, the final renders, the pose
//! corrections, the density spread.

use burn::module::Module;
use burn::tensor::Tensor;
use glam::DVec3;

use crate::data::projector::correction::PoseCorrection;
use crate::error::Result;
use crate::method::field_health::DensitySpread;
use ctadsa_ops::readback::host_vec;

use super::Trainer;

impl Trainer {
    /// Percentiles of the field's densities at the Gaussians' centres (one field forward).
    pub fn density_spread(&self) -> Option<DensitySpread> {
        DensitySpread::of(&host_vec(self.model().valid().densities()))
    }

    /// Host copy of the Gaussians: `(means, scales, rotations, densities)` row-major.
    pub fn host_gaussians(&self) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let m = self.model().valid();
        let v2 = |t: Tensor<2>| host_vec(t);
        let d = host_vec(m.densities());
        (v2(m.means.val()), v2(m.scales()), v2(m.rotations.val()), d)
    }

    /// Final renders of all views `[V][H·W]`.
    pub fn render_all(&self) -> Result<Vec<Vec<f32>>> {
        let m = self.model().valid();
        let gaussians = m.gaussians();
        let img = match &self.poses {
            None => ctadsa_render::render(&gaussians, &self.views, &self.settings)?,
            Some((poses, _)) => {
                let poses = poses.valid();
                let mut per_view = Vec::with_capacity(self.views.len());
                for v in 0..self.views.len() {
                    let seen = poses.apply(&gaussians, v);
                    per_view.push(ctadsa_render::render(&seen, &self.views.select(&[v])?, &self.settings)?);
                }
                Tensor::cat(per_view, 0)
            }
        };
        let (w, h) = self.views.image_size();
        let flat: Vec<f32> = host_vec(img);
        Ok(flat.chunks((w * h) as usize).map(<[f32]>::to_vec).collect())
    }

    /// The learned pose corrections of the run's views (`None` when pose refinement is off).
    pub fn pose_corrections(&self) -> Option<Vec<PoseCorrection>> {
        self.poses.as_ref().map(|(p, _)| p.corrections())
    }

    /// Centre of mass of the Gaussians (mm), for quick diagnostics.
    pub fn centroid(&self) -> DVec3 {
        let (m, ..) = self.host_gaussians();
        let n = (m.len() / 3).max(1) as f64;
        m.chunks_exact(3).fold(DVec3::ZERO, |acc, c| acc + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)) / n
    }
}
