//! The simulated acquisition: the views imaged by the voxel projector (pose errors, noise) and
//! written with their pictures.

use std::path::Path;

use ctadsa_render::{ConeBeamView, TigreGeometry};
use glam::DVec3;

use super::SynthConfig;
use super::presets::view_preset;
use crate::data::case::images::{Image, write_png16, write_preview_png, write_rgb_or_grey, write_tiff_f32};
use crate::data::case::{ViewEntry, ViewGeometry};
use crate::data::mesh::TriMesh;
use crate::data::mesh::render_png::{Coloured, standard_views, write_mesh_png};
use crate::data::projector::correction::{PoseCorrection, corrected_view, random_correction};
use crate::data::projector::project_volume;
use crate::data::volume::Volume;
use crate::error::{CoreError, Result};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The simulated acquisition: view names and geometries, the views as imaged (with the pose
/// errors when set), the images (noise applied, normalised when asked) and the pose errors.
pub(super) struct Acquisition {
    pub(super) names: Vec<String>,
    pub(super) geometries: Vec<TigreGeometry>,
    pub(super) images: Vec<Vec<f32>>,
    pub(super) normalised_by: Option<f64>,
    pub(super) view_corrections: Option<Vec<PoseCorrection>>,
    /// Views that see only part of the vessels.
    pub(super) warnings: Vec<String>,
    /// The views as imaged (pose errors applied).
    pub(super) imaged: Vec<ConeBeamView>,
    /// Per view, the arrival map of a time-resolved run ([`SynthConfig::arrival`]) and how late
    /// (frames) the view's frames are ([`ViewEntry::arrival_offset_frames`]).
    pub(super) arrivals: Option<Vec<(Image, f64)>>,
}

pub(super) fn acquire(cfg: &SynthConfig, complete: &Volume<f32>) -> Result<Acquisition> {
    let angles = view_preset(&cfg.views)?;
    let geometries: Vec<TigreGeometry> = angles
        .iter()
        .map(|(_, p, s)| {
            let mut g = cfg.geometry.geometry(*p, *s, 1);
            if let Some(n) = cfg.detector_px {
                g.detector_px = [n, n];
            }
            let b = cfg.binning.max(1);
            g.detector_px = g.detector_px.map(|d| (d / b).max(1));
            g.pixel_mm = g.pixel_mm.map(|p| p * b as f64);
            g
        })
        .collect();
    let views: Vec<ConeBeamView> =
        geometries.iter().map(ConeBeamView::from_tigre).collect::<std::result::Result<_, _>>()?;
    let contrast = complete.map(|v| v * cfg.contrast_per_mm as f32);
    let view_corrections: Option<Vec<PoseCorrection>> = cfg.pose_error.map(|e| {
        let mut rng = ChaCha8Rng::seed_from_u64(e.seed ^ 0x9053);
        (0..views.len())
            .map(|i| if i == 0 { [0.0; 6] } else { random_correction(e.translation_mm, e.rotation_deg, &mut rng) })
            .collect()
    });
    let imaged: Vec<ConeBeamView> = match &view_corrections {
        None => views,
        Some(c) => views.iter().zip(c).map(|(v, c)| corrected_view(v, c)).collect::<std::result::Result<_, _>>()?,
    };
    let mut warnings = Vec::new();
    for (name, view) in angles.iter().map(|(name, _, _)| name).zip(&imaged) {
        // An empty volume is named by the meshes' own check.
        let Some(on) = share_on_detector(complete, view) else { continue };
        if on <= 0.0 {
            return Err(CoreError::invalid(format!(
                "view `{name}`: no vessel projects onto its detector (the tree lies outside the view's field of view; \
                 check --translate-mm, --pose-error-mm, --views and the detector size)"
            )));
        }
        if on < 0.999 {
            warnings.push(format!(
                "view `{name}`: {:.1} % of the vessel volume projects outside the detector (cut off in this view)",
                100.0 * (1.0 - on)
            ));
        }
    }
    let mut images = project_volume(&contrast, &imaged);
    for (i, img) in images.iter_mut().enumerate() {
        cfg.noise.apply(img, i as u64);
    }
    let max = images.iter().flat_map(|i| i.iter()).copied().fold(0.0f32, f32::max);
    let normalised_by = (cfg.normalise && max > 0.0).then_some(max as f64);
    if let Some(m) = normalised_by {
        images.iter_mut().for_each(|img| img.iter_mut().for_each(|v| *v /= m as f32));
    }
    let names = angles.into_iter().map(|(name, _, _)| name).collect();
    Ok(Acquisition { names, geometries, images, normalised_by, view_corrections, warnings, imaged, arrivals: None })
}

/// The share (0–1) of `occupancy`'s total that projects onto `view`'s detector, each voxel
/// counted at its centre; `None` when the volume is empty.
pub(super) fn share_on_detector(occupancy: &Volume<f32>, view: &ConeBeamView) -> Option<f64> {
    let (w, h) = (view.width() as f64, view.height() as f64);
    let [nx, ny, nz] = occupancy.grid.dims;
    let (mut on, mut total) = (0.0f64, 0.0f64);
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let v = occupancy.get(i, j, k) as f64;
                if v <= 0.0 {
                    continue;
                }
                total += v;
                let p = occupancy.index_to_world.transform_point3(DVec3::new(i as f64, j as f64, k as f64));
                if view.project(p).is_some_and(|uv| (0.0..w).contains(&uv.x) && (0.0..h).contains(&uv.y)) {
                    on += v;
                }
            }
        }
    }
    (total > 0.0).then(|| on / total)
}

/// Writes every view (TIFF, 16-bit PNG, preview) and the pictures; returns the case's entries.
pub(super) fn write_views(
    out: &Path,
    acq: Acquisition,
    prior_mesh: &TriMesh,
    missing_mesh: &TriMesh,
) -> Result<Vec<ViewEntry>> {
    let mut entries = Vec::new();
    let display_max = acq.images.iter().flat_map(|i| i.iter()).copied().fold(0.0f32, f32::max);
    let mut strip: Vec<Image> = Vec::new();
    for (i, ((name, geom), data)) in acq.names.iter().zip(&acq.geometries).zip(acq.images).enumerate() {
        let img = Image { width: geom.detector_px[0], height: geom.detector_px[1], data };
        let (arrival, arrival_offset_frames) = match acq.arrivals.as_ref().map(|maps| &maps[i]) {
            Some((map, offset)) => {
                let relative = format!("views/{name}-arrival.tiff");
                write_tiff_f32(&out.join(&relative), map)?;
                (Some(relative), *offset)
            }
            None => (None, 0.0),
        };
        write_tiff_f32(&out.join(format!("views/{name}.tiff")), &img)?;
        let scale = write_png16(&out.join(format!("views/{name}.png")), &img)?;
        write_preview_png(&out.join(format!("pictures/view-{name}.png")), &img, 0.0, display_max, true)?;
        entries.push(ViewEntry {
            name: name.clone(),
            image: format!("views/{name}.tiff"),
            png_scale: Some(scale),
            preview_png: Some(format!("views/{name}.png")),
            geometry: ViewGeometry::from_tigre(geom),
            arrival,
            arrival_offset_frames,
        });
        strip.push(img);
    }
    write_view_strip(&out.join("pictures/views.png"), &strip, display_max)?;
    write_mesh_png(
        &out.join("pictures/meshes.png"),
        &[Coloured { mesh: prior_mesh, rgb: [200, 60, 50] }, Coloured { mesh: missing_mesh, rgb: [50, 110, 220] }],
        &standard_views(360),
    )?;
    Ok(entries)
}

/// Side-by-side 8-bit previews of the views (inverted, common scale).
pub(super) fn write_view_strip(path: &Path, images: &[Image], max: f32) -> Result<()> {
    let h = images.iter().map(|i| i.height).max().unwrap_or(1);
    let w: u32 = images.iter().map(|i| i.width).sum();
    let mut px = vec![255u8; (w * h) as usize];
    let mut x0 = 0usize;
    for img in images {
        for r in 0..img.height as usize {
            for c in 0..img.width as usize {
                let t = (img.data[r * img.width as usize + c] / max.max(1e-12)).clamp(0.0, 1.0);
                px[r * w as usize + x0 + c] = (255.0 * (1.0 - t)).round() as u8;
            }
        }
        x0 += img.width as usize;
    }
    write_rgb_or_grey(path, w, h, px, 1)
}
