//! A run's views, images and working box, and the initial density.

use ctadsa_render::{ConeBeamView, ViewSet};

use crate::config::{Config, WorkingBoxSource};
use crate::data::case::Case;
use crate::data::case::images::{Image, bin_image};
use crate::data::mesh::TriMesh;
use crate::data::volume::BoxMm;
use crate::error::{CoreError, Result};
use crate::method::model::{GaussianInit, ScaleBounds};
use crate::method::working_box::working_box_from_inputs;

/// The case's images and views after the run's view selection and binning.
pub fn prepare_views(case: &Case, cfg: &Config) -> Result<(ViewSet, Vec<Image>)> {
    let case = crate::method::arrival::run_case(case, cfg)?;
    let b = cfg.run.image_binning.max(1);
    let (w, h) = case.views.image_size();
    if b > w.min(h) {
        return Err(CoreError::invalid(format!(
            "config `run.image_binning` = {b} is larger than the {w} × {h} px detector of {}",
            case.dir.display()
        )));
    }
    let views: Vec<ConeBeamView> =
        case.views.views().iter().map(|v| v.binned(b)).collect::<std::result::Result<_, _>>()?;
    let images: Vec<Image> = case.images.iter().map(|img| bin_image(img, b)).collect();
    Ok((ViewSet::new(views)?, images))
}

/// Density that makes the initial renders carry the images' total intensity: the detector
/// integral of a blob is its mass over depth² (normalised image coordinates).
pub fn estimate_initial_density(views: &ViewSet, images: &[Image], init: &GaussianInit, bounds: ScaleBounds) -> f64 {
    let mut masses = Vec::new();
    for (v, img) in views.views().iter().zip(images) {
        let [fx, fy] = v.intrinsics().focal_px;
        let depth = v.source_mm().length();
        let sum: f64 = img.data.iter().map(|&x| x.max(0.0) as f64).sum();
        masses.push(sum / (fx * fy) * depth * depth);
    }
    let target_mass = masses.iter().sum::<f64>() / masses.len().max(1) as f64;
    let unit_mass: f64 = init
        .raw_scales
        .chunks_exact(3)
        .map(|r| {
            let s: f64 = r.iter().map(|&x| bounds.scale_mm_f64(x as f64)).product();
            (2.0 * std::f64::consts::PI).powf(1.5) * s
        })
        .sum();
    if unit_mass > 0.0 && target_mass > 0.0 { target_mass / unit_mass } else { 1.0 }
}

/// The run's working box (`run.working_box`).
pub fn run_working_box(
    case: &Case,
    cfg: &Config,
    views: &ViewSet,
    images: &[Image],
    prior: Option<&TriMesh>,
) -> Result<BoxMm> {
    match cfg.run.working_box {
        WorkingBoxSource::Case => Ok(case.file.volume.bounds()),
        WorkingBoxSource::Inputs => working_box_from_inputs(views.views(), images, prior, cfg.init.mask_threshold),
    }
}

/// Refuses before training an output grid (`output.voxel_mm` over the working box) that the
/// outputs could not be written on.
pub(super) fn check_output_grid(cfg: &Config, working_box: &BoxMm, case_voxel_mm: f64) -> Result<()> {
    let voxel = if cfg.output.voxel_mm > 0.0 { cfg.output.voxel_mm } else { case_voxel_mm };
    crate::data::volume::Grid::covering(working_box, voxel)
        .map(|_| ())
        .map_err(|e| CoreError::invalid(format!("config key `output.voxel_mm` = {voxel} mm: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn initial_density_makes_the_blobs_carry_the_images_mass() {
        let view = ConeBeamView::from_tigre(&ctadsa_render::TigreGeometry::reference(0.0)).unwrap();
        let views = ViewSet::new(vec![view]).unwrap();
        let (w, h) = (view.width(), view.height());
        let bounds = ScaleBounds { min_mm: 0.1, max_mm: 4.0 };
        let raw = bounds.inverse(1.0);
        let init =
            GaussianInit { means: vec![0.0; 6], raw_scales: vec![raw; 6], rotations: [1.0, 0.0, 0.0, 0.0].repeat(2) };
        let image = |v: f32| Image { width: w, height: h, data: vec![v; (w * h) as usize] };
        let d1 = estimate_initial_density(&views, &[image(1.0)], &init, bounds);
        let d2 = estimate_initial_density(&views, &[image(2.0)], &init, bounds);
        assert!(d1 > 0.0 && (d2 / d1 - 2.0).abs() < 1e-9, "density scales with the image mass: {d1} {d2}");
        assert_eq!(estimate_initial_density(&views, &[image(0.0)], &init, bounds), 1.0, "empty images: 1");
    }
}
