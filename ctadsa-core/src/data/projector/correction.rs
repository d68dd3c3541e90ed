//! Rigid corrections of a view's pose: `[ω (rad), t (mm)]` seen by the nominal view as
//! `R(ω) x + t` (a rotation about the isocentre, then a translation), the corrected views, and
//! how far one correction is from another (for the pose-refinement study and perturbed cases).

use ctadsa_render::{ConeBeamView, RenderError};
use glam::{DMat3, DQuat, DVec3};

/// One view's correction `[ω_x, ω_y, ω_z (rad), t_x, t_y, t_z (mm)]`.
pub type PoseCorrection = [f64; 6];

/// The rotation of a correction (f64, exact).
pub fn correction_rotation(c: &PoseCorrection) -> DMat3 {
    DMat3::from_quat(DQuat::from_scaled_axis(DVec3::new(c[0], c[1], c[2])))
}

/// Where a world point `x` appears to the nominal view under correction `c`: `R(ω) x + t`.
pub fn apply_correction(c: &PoseCorrection, x: DVec3) -> DVec3 {
    correction_rotation(c) * x + DVec3::new(c[3], c[4], c[5])
}

/// The view that sees the world as `view` sees it through correction `c` (for exporting
/// refined geometry and for making perturbed test cases).
pub fn corrected_view(view: &ConeBeamView, c: &PoseCorrection) -> Result<ConeBeamView, RenderError> {
    let r = correction_rotation(c);
    view.moved(r.transpose(), -(r.transpose() * DVec3::new(c[3], c[4], c[5])))
}

/// Mean and largest distance (detector pixels) between where `points` (world mm) project in two
/// views of the same detector: the reprojection error of one pose against another.
pub fn reprojection_error_px(a: &ConeBeamView, b: &ConeBeamView, points: &[DVec3]) -> (f64, f64) {
    let d: Vec<f64> = points.iter().filter_map(|&p| Some((a.project(p)? - b.project(p)?).length())).collect();
    let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
    (mean, d.iter().copied().fold(0.0, f64::max))
}

/// A random correction: a rotation of `rotation_deg` about a random axis and a translation of
/// `translation_mm` in a random direction (for perturbation studies).
pub fn random_correction(translation_mm: f64, rotation_deg: f64, rng: &mut impl rand::RngExt) -> PoseCorrection {
    let mut unit = || loop {
        let v = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let l = v.length();
        if (0.1..=1.0).contains(&l) {
            break v / l;
        }
    };
    let (axis, dir) = (unit(), unit());
    let w = axis * rotation_deg.to_radians();
    let t = dir * translation_mm;
    [w.x, w.y, w.z, t.x, t.y, t.z]
}

/// How far a learned correction is from the true one, for one view.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseError {
    /// The view's index in the case.
    pub view: usize,
    /// Angle of `R_learned · R_trueᵀ` (degrees).
    pub rotation_error_deg: f64,
    /// Distance between the learned and true translations (mm).
    pub translation_error_mm: f64,
    /// Mean reprojection error of the nominal (uncorrected) view against the true one (px).
    pub reprojection_before_px: f64,
    /// Mean reprojection error of the refined view against the true one (px).
    pub reprojection_after_px: f64,
}

/// Compares learned corrections of `views` with the true ones on `points` (world mm).
pub fn pose_errors(
    views: &[(usize, ConeBeamView)],
    learned: &[PoseCorrection],
    truth: &[PoseCorrection],
    points: &[DVec3],
) -> Result<Vec<PoseError>, RenderError> {
    let mut out = Vec::new();
    for ((index, view), (l, t)) in views.iter().zip(learned.iter().zip(truth)) {
        let true_view = corrected_view(view, t)?;
        let refined = corrected_view(view, l)?;
        let dr = correction_rotation(l) * correction_rotation(t).transpose();
        let angle = ((dr.x_axis.x + dr.y_axis.y + dr.z_axis.z - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
        out.push(PoseError {
            view: *index,
            rotation_error_deg: angle.to_degrees(),
            translation_error_mm: (DVec3::new(l[3], l[4], l[5]) - DVec3::new(t[3], t[4], t[5])).length(),
            reprojection_before_px: reprojection_error_px(view, &true_view, points).0,
            reprojection_after_px: reprojection_error_px(&refined, &true_view, points).0,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrected_view_sees_the_corrected_point() {
        let view = ConeBeamView::from_tigre(&ctadsa_render::TigreGeometry::reference(-90.0)).unwrap();
        let c: PoseCorrection = [0.01, 0.02, -0.015, 2.0, -1.0, 0.5];
        let moved = corrected_view(&view, &c).unwrap();
        for x in [DVec3::new(10.0, -5.0, 3.0), DVec3::new(-30.0, 20.0, -12.0)] {
            let a = moved.project(x).unwrap();
            let b = view.project(apply_correction(&c, x)).unwrap();
            assert!((a - b).length() < 1e-9, "{a:?} vs {b:?}");
        }
    }
}
