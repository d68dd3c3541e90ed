//! The prior from a CTA segmentation: chosen labels of a NIfTI label volume → surface mesh in
//! world mm, small islands removed, optionally cut to what the DSA views can see.

use std::path::Path;

use ctadsa_render::ConeBeamView;
use glam::DVec3;

use crate::data::mesh::TriMesh;
use crate::data::mesh::marching::extract_isosurface;
use crate::data::volume::Volume;
use crate::data::volume::nifti_io::read_nifti;
use crate::error::{CoreError, Result};

/// Which views must see a triangle for it to stay in the prior.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visibility {
    /// Keep everything.
    All,
    /// Keep triangles whose three corners project inside every view's detector.
    SeenByEveryView,
    /// Keep triangles seen by at least one view.
    SeenByAnyView,
}

/// Options of [`prior_from_labels`].
#[derive(Debug, Clone, PartialEq)]
pub struct LabelPriorOptions {
    /// Label values making the vessels (empty = every non-zero label).
    pub labels: Vec<u32>,
    /// Connected components with less surface than this (mm²) are dropped.
    pub min_island_mm2: f64,
    /// Translation (mm) added to the file's world coordinates (e.g. to put the isocentre at the
    /// origin); applied before the visibility test.
    pub translation_mm: [f64; 3],
}

/// What [`prior_from_labels`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelPrior {
    pub mesh: TriMesh,
    /// Voxels carrying the chosen labels.
    pub voxels: usize,
    /// Islands dropped by the area threshold.
    pub islands_dropped: usize,
    /// Triangles dropped as not visible.
    pub hidden_triangles: usize,
}

/// Reads the label volume and builds the prior surface (world mm from the file's affine, plus
/// `translation_mm`).
pub fn prior_from_labels(
    path: &Path,
    options: &LabelPriorOptions,
    views: &[ConeBeamView],
    visibility: Visibility,
) -> Result<LabelPrior> {
    let volume = read_nifti(path)?;
    let labels = &options.labels;
    let data: Vec<f32> = volume
        .data
        .iter()
        .map(|&v| {
            let l = v.round() as i64;
            (l > 0 && (labels.is_empty() || labels.contains(&(l as u32)))) as u8 as f32
        })
        .collect();
    let voxels = data.iter().filter(|&&v| v > 0.0).count();
    if voxels == 0 {
        let present = present_labels(&volume);
        return Err(CoreError::format(
            path,
            format!("no voxel carries the selected labels {labels:?} (labels present: {present:?})"),
        ));
    }
    let mask = Volume { grid: volume.grid, index_to_world: volume.index_to_world, data };
    let mut mesh = extract_isosurface(&mask, 0.5);
    let shift = DVec3::from_array(options.translation_mm);
    mesh.vertices.iter_mut().for_each(|v| *v += shift);
    let (mut mesh, islands_dropped) = mesh.without_islands_below(options.min_island_mm2);
    let before = mesh.faces.len();
    if visibility != Visibility::All && !views.is_empty() {
        mesh = keep_visible(&mesh, views, visibility);
    }
    let hidden_triangles = before - mesh.faces.len();
    if mesh.is_empty() {
        return Err(CoreError::format(
            path,
            "the prior is empty after island removal and the visibility cut (views not pointing at it? \
             check --prior-shift-mm)",
        ));
    }
    Ok(LabelPrior { mesh, voxels, islands_dropped, hidden_triangles })
}

/// [`prior_from_labels`] with the translation that puts the centre of the labels' surface
/// (before island removal and the visibility cut) at the isocentre, instead of
/// `options.translation_mm`; returns the prior and that translation (mm). For a CTA whose
/// coordinates are not those of the C-arm.
pub fn centred_prior_from_labels(
    path: &Path,
    options: &LabelPriorOptions,
    views: &[ConeBeamView],
    visibility: Visibility,
) -> Result<(LabelPrior, [f64; 3])> {
    let uncut = LabelPriorOptions { translation_mm: [0.0; 3], ..options.clone() };
    let whole = prior_from_labels(path, &uncut, &[], Visibility::All)?;
    let (lo, hi) = whole.mesh.bounds_mm().ok_or_else(|| CoreError::format(path, "the prior surface is empty"))?;
    let shift = (-(lo + hi) * 0.5).to_array();
    let centred = LabelPriorOptions { translation_mm: shift, ..options.clone() };
    Ok((prior_from_labels(path, &centred, views, visibility)?, shift))
}

/// The distinct positive label values of a volume (at most 64 listed).
pub fn present_labels(volume: &Volume<f32>) -> Vec<u32> {
    let mut set = std::collections::BTreeSet::new();
    for &v in &volume.data {
        let l = v.round() as i64;
        if l > 0 && set.len() < 64 {
            set.insert(l as u32);
        }
    }
    set.into_iter().collect()
}

fn seen(view: &ConeBeamView, p: DVec3) -> bool {
    view.project(p).is_some_and(|q| {
        q.x >= -0.5 && q.y >= -0.5 && q.x <= view.width() as f64 - 0.5 && q.y <= view.height() as f64 - 0.5
    })
}

/// The triangles whose three corners the views see (every view or any view), unused vertices
/// removed.
pub fn keep_visible(mesh: &TriMesh, views: &[ConeBeamView], visibility: Visibility) -> TriMesh {
    let visible: Vec<bool> = mesh
        .vertices
        .iter()
        .map(|&p| match visibility {
            Visibility::All => true,
            Visibility::SeenByEveryView => views.iter().all(|v| seen(v, p)),
            Visibility::SeenByAnyView => views.iter().any(|v| seen(v, p)),
        })
        .collect();
    let mut map = vec![u32::MAX; mesh.vertices.len()];
    let mut out = TriMesh::default();
    for f in &mesh.faces {
        if f.iter().all(|&i| visible[i as usize]) {
            let g = f.map(|i| {
                if map[i as usize] == u32::MAX {
                    map[i as usize] = out.vertices.len() as u32;
                    out.vertices.push(mesh.vertices[i as usize]);
                }
                map[i as usize]
            });
            out.faces.push(g);
        }
    }
    out
}
