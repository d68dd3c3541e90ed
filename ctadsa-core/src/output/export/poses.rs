//! `poses.json`: the refined views of a run with pose refinement, and their errors.

use std::path::Path;

use glam::DVec3;

use crate::data::case::{Case, ViewGeometry};
use crate::data::mesh::TriMesh;
use crate::data::projector::correction::{PoseCorrection, PoseError, corrected_view, pose_errors};
use crate::error::{Result, to_json, write_file};
use crate::method::train::Trainer;
use ctadsa_render::ConeBeamView;

/// With pose refinement: writes `poses.json` (the corrections and the refined geometry of every
/// view of the run, as world-to-camera matrices at the case's detector) and, when the case knows
/// the true corrections, returns how far the refined views are from them.
pub(super) fn write_poses(
    dir: &Path,
    case: &Case,
    trainer: &Trainer,
    prior: Option<&TriMesh>,
) -> Result<Option<Vec<PoseError>>> {
    let Some(learned) = trainer.pose_corrections() else {
        return Ok(None);
    };
    let indices: Vec<usize> = if trainer.cfg().run.views.is_empty() {
        (0..case.views.len()).collect()
    } else {
        trainer.cfg().run.views.clone()
    };
    let nominal: Vec<(usize, ConeBeamView)> = indices.iter().map(|&i| (i, case.views.views()[i])).collect();
    let mut entries = Vec::new();
    for ((i, view), c) in nominal.iter().zip(&learned) {
        let refined = corrected_view(view, c)?;
        let intr = refined.intrinsics();
        let m = refined.world_to_camera().transpose().to_cols_array_2d();
        entries.push(serde_json::json!({
            "view": i,
            "name": case.file.views[*i].name,
            "rotation_deg": [c[0].to_degrees(), c[1].to_degrees(), c[2].to_degrees()],
            "translation_mm": [c[3], c[4], c[5]],
            "geometry": ViewGeometry::Matrix {
                world_to_camera: m,
                focal_px: intr.focal_px,
                principal_px: intr.principal_px,
                detector_px: [refined.width(), refined.height()],
            },
        }));
    }
    let poses_path = dir.join("poses.json");
    let text = to_json(
        &serde_json::json!({
            "convention": "view v sees world point x where the nominal view sees R(ω) x + t (rotation about the isocentre, then translation); geometry = the refined view",
            "views": entries,
        }),
        &poses_path,
    )?;
    write_file(&poses_path, text.as_bytes())?;
    let truth = case.file.ground_truth.as_ref().and_then(|g| g.view_corrections.as_ref());
    let Some(truth) = truth else {
        return Ok(None);
    };
    let truth: Vec<PoseCorrection> = indices.iter().map(|&i| truth.get(i).copied().unwrap_or([0.0; 6])).collect();
    let points: Vec<DVec3> = match prior {
        Some(p) if !p.vertices.is_empty() => {
            p.vertices.iter().step_by((p.vertices.len() / 2000).max(1)).copied().collect()
        }
        _ => vec![DVec3::ZERO],
    };
    Ok(Some(pose_errors(&nominal, &learned, &truth, &points)?))
}
