//! The anatomy rasterised to occupancy volumes: the complete one and one prior per threshold.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::{Anatomy, SynthConfig};
use crate::data::tree::VesselTree;
use crate::data::tree::prior::{PriorThreshold, split_by_diameter};
use crate::data::tree::swc::read_swc;
use crate::data::volume::edt::local_thickness;
use crate::data::volume::nifti_io::read_nifti;
use crate::data::volume::rasterize::rasterize_segments;
use crate::data::volume::{BoxMm, Grid, Volume};
use crate::error::{CoreError, Result};

pub(super) fn rotation(deg: [f64; 3]) -> DMat3 {
    let [x, y, z] = deg.map(f64::to_radians);
    DMat3::from_rotation_z(z) * DMat3::from_rotation_y(y) * DMat3::from_rotation_x(x)
}

/// The anatomy as occupancy volumes: complete and, per prior threshold, prior.
pub(super) struct Rasterised {
    pub(super) complete: Volume<f32>,
    pub(super) priors: Vec<(f64, Volume<f32>)>,
    pub(super) tree: Option<VesselTree>,
    pub(super) source: String,
    pub(super) warnings: Vec<String>,
}

pub(super) fn from_tree(
    mut tree: VesselTree,
    cfg: &SynthConfig,
    source: String,
    warnings: Vec<String>,
) -> Result<Rasterised> {
    if tree.segments().is_empty() {
        let why = warnings.first().map_or(String::new(), |w| format!("; first problem: {w}"));
        return Err(CoreError::invalid(format!(
            "{source}: the tree has no vessel segment ({} nodes, none with a usable parent){why}",
            tree.nodes.len()
        )));
    }
    tree.centre_on_isocentre();
    tree.transform(rotation(cfg.rotation_deg), DVec3::from(cfg.translation_mm));
    let (lo, hi) = tree.bounds_mm().ok_or_else(|| CoreError::invalid("the tree is empty"))?;
    let bounds = BoxMm { min_mm: lo.to_array(), max_mm: hi.to_array() }.padded(1.0);
    let grid = match cfg.voxel_mm {
        Some(v) => Grid::covering(&bounds, v)?,
        None => Grid::with_longest_side(&bounds, 256)?,
    };
    let complete = rasterize_segments(&tree.segments(), grid, cfg.supersample);
    let mut priors = Vec::new();
    for t in &cfg.priors {
        let d = t.diameter_mm(&tree)?;
        let split = split_by_diameter(&tree, d);
        priors.push((d, rasterize_segments(&split.prior, grid, cfg.supersample)));
    }
    Ok(Rasterised { complete, priors, tree: Some(tree), source, warnings })
}

pub(super) fn from_labels(
    path: &Path,
    labels: &[u32],
    prior_drop_labels: &[u32],
    cfg: &SynthConfig,
) -> Result<Rasterised> {
    if cfg.rotation_deg != [0.0; 3] || cfg.translation_mm != [0.0; 3] {
        return Err(CoreError::invalid(
            "rotation/translation are supported for trees only; resample a label volume before synthesis",
        ));
    }
    let vol = read_nifti(path)?;
    let selected: Vec<u8> = vol
        .data
        .iter()
        .map(|&v| {
            let l = v.round() as i64;
            (l > 0 && (labels.is_empty() || labels.contains(&(l as u32)))) as u8
        })
        .collect();
    if !selected.contains(&1) {
        return Err(CoreError::format(path, format!("no voxel carries the selected labels {labels:?}")));
    }
    let dropped: Vec<bool> =
        vol.data.iter().map(|&v| prior_drop_labels.contains(&(v.round().max(0.0) as u32))).collect();
    if let Some(l) = prior_drop_labels.iter().find(|&&l| !vol.data.iter().any(|&v| v.round() == l as f32)) {
        return Err(CoreError::format(path, format!("no voxel carries label {l}, which the prior should leave out")));
    }
    // Axis-aligned on the file's voxel sizes, centred on the isocentre (the direction matrix is
    // ignored, as in the reference implementation).
    let mut grid = vol.grid;
    let size = [0, 1, 2].map(|a| grid.dims[a] as f64 * grid.spacing_mm[a]);
    grid.origin_mm = size.map(|s| -s / 2.0);
    let mask = Volume { grid, index_to_world: grid.index_to_world(), data: selected };
    let thickness = local_thickness(&mask);
    let complete = mask.map(|m| m as f32);
    let mut priors = Vec::new();
    for t in &cfg.priors {
        let d = match *t {
            PriorThreshold::DiameterMm(d) => d,
            PriorThreshold::LengthPercentile(p) => {
                // Percentile of the vessel volume by local thickness.
                let mut th: Vec<f64> = thickness.iter().copied().filter(|&x| x > 0.0).collect();
                th.sort_by(f64::total_cmp);
                th.get(((p / 100.0) * th.len() as f64) as usize).copied().unwrap_or(f64::INFINITY)
            }
        };
        let data = mask
            .data
            .iter()
            .zip(&thickness)
            .zip(&dropped)
            .map(|((&m, &t), &drop)| (m == 1 && t >= d && !drop) as u8 as f32)
            .collect();
        priors.push((d, Volume { grid, index_to_world: grid.index_to_world(), data }));
    }
    Ok(Rasterised {
        complete,
        priors,
        tree: None,
        source: format!("label volume {}", path.display()),
        warnings: Vec::new(),
    })
}

pub(super) fn occupancy_volume_mm3(v: &Volume<f32>) -> f64 {
    let h = v.grid.spacing_mm;
    v.data.iter().map(|&x| x as f64).sum::<f64>() * h[0] * h[1] * h[2]
}

/// The anatomy rasterised: the complete occupancy and one prior per threshold.
pub(super) fn rasterise_anatomy(cfg: &SynthConfig) -> Result<Rasterised> {
    match &cfg.anatomy {
        Anatomy::Procedural(p) => from_tree(
            p.generate()?,
            cfg,
            format!(
                "procedural CCO tree (seed {}, {} terminals, ctadsa {})",
                p.seed,
                p.terminals,
                env!("CARGO_PKG_VERSION")
            ),
            Vec::new(),
        ),
        Anatomy::Swc { path } => {
            let f = read_swc(path)?;
            let warnings = f.warnings.iter().map(|w| format!("{}:{}: {}", path.display(), w.line, w.problem)).collect();
            from_tree(f.tree, cfg, format!("SWC tree {}", path.display()), warnings)
        }
        Anatomy::Labels { path, labels, prior_drop_labels } => from_labels(path, labels, prior_drop_labels, cfg),
    }
}
