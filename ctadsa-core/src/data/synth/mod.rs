//! Synthetic cases: anatomy (a vessel tree or a label volume) → occupancy volume → complete,
//! prior and missing meshes → DSA views by the independent voxel projector → a case folder.

mod acquisition;
pub mod arrival;
mod config;
pub mod presets;
mod provenance;
mod rasterise;

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::data::case::images::{Image, NO_ARRIVAL};
use crate::data::case::{
    CASE_FILE, CASE_FORMAT, CASE_VERSION, CaseFile, GroundTruth, ImageValues, MAX_ARRIVAL_FRAME, PriorEntry,
    Provenance, VolumeEntry,
};
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::write_mesh;
use crate::data::mesh::marching::extract_isosurface;
use crate::data::tree::swc::write_swc;
use crate::data::volume::Volume;
use crate::data::volume::nifti_io::write_nifti;
use crate::error::{CoreError, Result, remove_path, write_file};
use arrival::arrival_map;

use acquisition::{acquire, write_views};
pub use config::{Anatomy, MAX_SUPERSAMPLE, PoseErrorSpec, SynthConfig};
use provenance::{provenance_markdown, provenance_notes};
use rasterise::{Rasterised, occupancy_volume_mm3, rasterise_anatomy};

/// What a synthesis produced, for reports.
#[derive(Debug, Clone, Serialize)]
pub struct SynthSummary {
    pub dir: PathBuf,
    pub voxels: [usize; 3],
    pub voxel_mm: [f64; 3],
    pub views: usize,
    pub prior_thresholds_mm: Vec<f64>,
    /// Vessel volume (mm³) of the complete anatomy and of the first prior.
    pub complete_volume_mm3: f64,
    pub prior_volume_mm3: f64,
    pub warnings: Vec<String>,
}

/// The ground truth (complete mesh, occupancy, tree) and every prior with its missing vessels,
/// written under `out`.
fn write_truth_and_priors(r: &Rasterised, out: &Path) -> Result<WrittenPriors> {
    let grid = r.complete.grid;
    let complete_mesh = extract_isosurface(&r.complete, 0.5);
    if complete_mesh.is_empty() {
        let thickest = r.tree.as_ref().map_or(String::new(), |t| {
            let r = t.nodes.iter().map(|n| n.radius_mm).fold(0.0, f64::max);
            format!(" (thickest vessel radius {r} mm)")
        });
        // A tree in another unit (m, µm) spans far less or far more than a head.
        let unit_hint = r.tree.as_ref().and_then(|t| {
            let (lo, hi) = t.bounds_mm()?;
            let span = (hi - lo).length();
            (!(10.0..=1000.0).contains(&span)).then(|| {
                format!(
                    "; the tree spans {span:.4} mm where a cerebral tree spans 50–300 mm: are its coordinates in mm?"
                )
            })
        });
        let voxel = grid.spacing_mm[0];
        return Err(CoreError::invalid(format!(
            "the anatomy produced no surface at {voxel} mm voxels{thickest}: its vessels are thinner than a \
             voxel; set a smaller voxel size{}",
            unit_hint.unwrap_or_default()
        )));
    }
    write_mesh(&out.join("gt/complete.obj"), &complete_mesh)?;
    write_nifti(&out.join("gt/occupancy.nii.gz"), &r.complete, "ctadsa vessel occupancy")?;
    if let Some(tree) = &r.tree {
        write_swc(&out.join("gt/tree.swc"), tree, "ctadsa: centred (and transformed) tree, mm")?;
    }
    let mut prior_entries = Vec::new();
    let mut first_meshes: Option<(TriMesh, TriMesh)> = None;
    for (d, prior) in &r.priors {
        let tag = format!("d{:.2}mm", d).replace('.', "p");
        let prior_mesh = extract_isosurface(prior, 0.5);
        let missing = Volume {
            grid,
            index_to_world: r.complete.index_to_world,
            data: r.complete.data.iter().zip(&prior.data).map(|(&c, &p)| (c - p).max(0.0)).collect(),
        };
        let missing_mesh = extract_isosurface(&missing, 0.5);
        write_mesh(&out.join(format!("priors/{tag}/prior.obj")), &prior_mesh)?;
        write_mesh(&out.join(format!("priors/{tag}/missing.obj")), &missing_mesh)?;
        prior_entries.push((*d, tag));
        if first_meshes.is_none() {
            first_meshes = Some((prior_mesh, missing_mesh));
        }
    }
    let (prior_mesh, missing_mesh) =
        first_meshes.ok_or_else(|| CoreError::invalid("at least one prior threshold is needed"))?;
    Ok(WrittenPriors { entries: prior_entries, prior_mesh, missing_mesh })
}

/// The priors written by [`write_truth_and_priors`].
struct WrittenPriors {
    /// (diameter threshold in mm, folder tag under `priors/`) of each prior.
    entries: Vec<(f64, String)>,
    /// The first prior's mesh and its missing vessels.
    prior_mesh: TriMesh,
    missing_mesh: TriMesh,
}

/// What [`synthesize`] writes into a case folder (besides `.tmp` files while it writes).
pub const CASE_OUTPUTS: [&str; 6] = [CASE_FILE, "PROVENANCE.md", "views", "priors", "gt", "pictures"];

/// Removes an earlier case from `dir` — [`CASE_OUTPUTS`] and nothing else the folder holds — so
/// that a case made again there keeps no prior, view or picture of the old one.
fn remove_case(dir: &Path) -> Result<()> {
    CASE_OUTPUTS.iter().try_for_each(|name| remove_path(&dir.join(name)))
}

/// Writes a synthetic case into `out`, reporting each step to `progress`. Files of an earlier
/// case there are overwritten, not removed ([`synthesize_replacing`] replaces one).
pub fn synthesize(cfg: &SynthConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<SynthSummary> {
    synthesize_into(cfg, out, false, progress)
}

/// [`synthesize`], replacing an earlier case in `out`: once the new case's anatomy and views
/// have passed their checks (a refused case leaves the old one as it was), the old case's files
/// ([`CASE_OUTPUTS`], nothing else) are removed, so that no prior, view or picture of it remains.
pub fn synthesize_replacing(cfg: &SynthConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<SynthSummary> {
    synthesize_into(cfg, out, true, progress)
}

fn synthesize_into(
    cfg: &SynthConfig,
    out: &Path,
    replace: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<SynthSummary> {
    if cfg.priors.is_empty() {
        return Err(CoreError::invalid("at least one prior threshold is needed"));
    }
    cfg.validate()?;
    progress("anatomy");
    let r = rasterise_anatomy(cfg)?;
    let grid = r.complete.grid;
    progress("projections");
    let mut acq = acquire(cfg, &r.complete)?;
    let (normalised_by, view_corrections, n_views) = (acq.normalised_by, acq.view_corrections.clone(), acq.names.len());
    let mut view_warnings = std::mem::take(&mut acq.warnings);
    if let Some(spec) = &cfg.arrival {
        let tree = r.tree.as_ref().ok_or_else(|| CoreError::invalid("arrival maps need a tree"))?;
        let arrivals: Vec<(Image, f64)> = acq
            .imaged
            .iter()
            .enumerate()
            .map(|(i, view)| (arrival_map(tree, view, i, spec), spec.delay_frames(i)))
            .collect();
        let frames = || arrivals.iter().flat_map(|(m, _)| m.data.iter().copied().filter(|&f| f != NO_ARRIVAL));
        let last = frames().fold(0.0f32, f32::max);
        if last > MAX_ARRIVAL_FRAME {
            return Err(CoreError::invalid(format!(
                "the arrival maps would reach frame {last} (a case holds at most {MAX_ARRIVAL_FRAME}): \
                 lower --arrival-fps ({} /s) or raise --flow-mm-s ({} mm/s)",
                spec.frames_per_s, spec.flow_mm_s
            )));
        }
        if frames().all(|f| f == last) {
            view_warnings.push(format!(
                "every vessel fills in frame {last}: the arrival maps say nothing about time \
                 (raise --arrival-fps or lower --flow-mm-s)"
            ));
        }
        acq.arrivals = Some(arrivals);
    }
    if replace {
        remove_case(out)?;
    }
    progress("meshes");
    let WrittenPriors { entries: prior_entries, prior_mesh, missing_mesh } = write_truth_and_priors(&r, out)?;
    progress("files");
    let entries = write_views(out, acq, &prior_mesh, &missing_mesh)?;
    let (d0, tag0) = &prior_entries[0];
    let bounds = grid.bounds();
    let case = CaseFile {
        format: CASE_FORMAT.into(),
        version: CASE_VERSION,
        name: cfg.name.clone(),
        provenance: Provenance {
            source: r.source.clone(),
            generator: format!(
                "ctadsa synth {} ({})",
                env!("CARGO_PKG_VERSION"),
                serde_json::to_string(cfg).unwrap_or_default()
            ),
            notes: provenance_notes(&cfg.anatomy),
        },
        image_values: ImageValues {
            units: "contrast × mm (line integral of the vessel occupancy × contrast_per_mm)".into(),
            normalised_by,
            contrast_per_mm: Some(cfg.contrast_per_mm),
        },
        volume: VolumeEntry {
            min_mm: bounds.min_mm,
            max_mm: bounds.max_mm,
            voxel_mm: grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min),
        },
        views: entries,
        prior: Some(PriorEntry {
            mesh: format!("priors/{tag0}/prior.obj"),
            description: match &cfg.anatomy {
                Anatomy::Labels { prior_drop_labels, .. } if !prior_drop_labels.is_empty() => {
                    format!("vessels with diameter ≥ {d0:.2} mm, without labels {prior_drop_labels:?}")
                }
                _ => format!("vessels with diameter ≥ {d0:.2} mm"),
            },
            threshold_mm: Some(*d0),
        }),
        ground_truth: Some(GroundTruth {
            complete_mesh: "gt/complete.obj".into(),
            missing_mesh: Some(format!("priors/{tag0}/missing.obj")),
            labels: Some("gt/occupancy.nii.gz".into()),
            tree: r.tree.as_ref().map(|_| "gt/tree.swc".into()),
            view_corrections,
        }),
    };
    case.save(out)?;
    write_file(&out.join("PROVENANCE.md"), provenance_markdown(&case).as_bytes())?;
    Ok(SynthSummary {
        dir: out.to_path_buf(),
        voxels: grid.dims,
        voxel_mm: grid.spacing_mm,
        views: n_views,
        prior_thresholds_mm: prior_entries.iter().map(|p| p.0).collect(),
        complete_volume_mm3: occupancy_volume_mm3(&r.complete),
        prior_volume_mm3: occupancy_volume_mm3(&r.priors[0].1),
        warnings: r.warnings.into_iter().chain(view_warnings).collect(),
    })
}
