//! The completed vessel tree as a centreline graph: the skeleton of the completed solid (the
//! density above the extraction level, joined with the prior's voxels where the prior is kept),
//! radii measured to the completed surface, each node marked as on a prior vessel or a new one;
//! written as SWC and VTK PolyData, scored against the case's true tree, and drawn.

use std::path::Path;

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::data::case::images::Image;
use crate::data::mesh::TriMesh;
use crate::data::mesh::distance::SurfaceIndex;
use crate::data::mesh::render_png::{Coloured, OrbitView, standard_views, write_mesh_png};
use crate::data::mesh::tubes::segment_tubes;
use crate::data::tree::swc::write_swc;
use crate::data::tree::vtp::write_vtp;
use crate::data::tree::{KIND_NEW_VESSEL, KIND_PRIOR_VESSEL, Segment, VesselTree};
use crate::data::volume::Volume;
use crate::data::volume::skeleton::{SkeletonParams, skeletonize_along};
use crate::error::Result;
use crate::eval::centreline_metrics::{CentrelineMatch, CentrelineScores, score_centreline};
use crate::output::arrival::arrival_agreement;
use crate::output::centring::{Centring, centre_nodes, centre_on_ridge};
use crate::output::confidence::{
    CONFIDENCE_BINS, ConfidenceBin, bin_of, branch_confidence, confidence_bins, confidence_rgb, node_confidence,
    without_branches, write_branches_csv,
};

/// The density over its level above which every voxel is as much a ridge as any other: the
/// axis of a vessel well above the level is found by the medial axis alone.
pub const RIDGE_CAP: f32 = 2.0;

/// How far (voxels of the traced grid) [`Centring::Ridge`] may move a node.
pub const RIDGE_SHIFT_VOXELS: f64 = 1.5;

/// What a run's centreline is and how it scores.
#[derive(Debug, Clone, Serialize)]
pub struct CentrelineSummary {
    pub nodes: usize,
    /// Total centreline length and the part on new vessels (mm).
    pub length_mm: f64,
    pub new_length_mm: f64,
    /// Against the case's true tree, when it has one.
    pub scores: Option<CentrelineScores>,
    /// Branches of the centreline, and those new.
    pub branches: usize,
    pub new_branches: usize,
    /// The new centreline by confidence ([`crate::output::confidence`]): length per bin, and
    /// with a true tree the part on a true vessel (precision per bin: the reliability diagram).
    pub confidence_bins: Vec<ConfidenceBin>,
    /// New branches left out because their arrival disagrees between the two views
    /// ([`ArrivalCheck`]); absent when the run has no arrival maps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub arrival_dropped_branches: Option<usize>,
}

/// The arrival check of a time-resolved 2-view run ([`crate::output::arrival`]): the run's
/// arrival maps and `output.arrival_*`.
#[derive(Debug, Clone, Copy)]
pub struct ArrivalCheck<'a> {
    /// Per view of the run, its arrival map (frames, −1 where no vessel fills).
    pub maps: &'a [Image],
    pub tolerance_frames: f64,
    pub min_agreement: f64,
    /// Where `maps` hide the prior's projection, the window (pixels) of
    /// [`crate::method::arrival::frames_seen`].
    pub exit_px: u32,
}

/// One part of the completed solid: its voxels and its surface.
#[derive(Clone, Copy)]
pub struct SolidPart<'a> {
    pub voxels: &'a Volume<u8>,
    pub surface: &'a TriMesh,
}

impl SolidPart<'_> {
    /// Distance (mm) from `p` to this part's surface when `p` lies in its voxels, else 0.
    fn depth(&self, index: &SurfaceIndex, p: DVec3) -> f64 {
        if self.voxels.is_set_at(p) { index.distance(p) } else { 0.0 }
    }
}

/// The centreline ([`skeletonize_along`]) of the extracted solid, joined with the prior's voxels when
/// `prior_kept`. A node's radius is the voxel estimate (boundary distance less half a voxel, at
/// least half a voxel), raised to its depth in the solid — the larger of its distances to the
/// surfaces of the parts it lies in (extracted iso-surface, prior mesh) — where that is larger
/// by at most a voxel: the voxel estimate steps and runs low on wide vessels, while the
/// iso-surface of a vessel one voxel wide lies closer to its axis than the vessel's wall. A
/// node within a voxel of the prior (inside, or nearer its surface than a voxel) is of type
/// [`KIND_PRIOR_VESSEL`], any other of type [`KIND_NEW_VESSEL`]. On a solid finer than the
/// density volume, `working_voxel_mm` (that volume's voxel) keeps both rules as they are there:
/// the prior's margin is that voxel and no radius is below half of it (a finer grid traces
/// thin vessels whole; it does not make a vessel near the prior new, nor resolve radii the
/// density does not). `bridges` (voxels on the same grid) are traced through as part of the
/// solid without being part of the extracted one. `relative`, the completion's density over
/// its local level on the solid's grid, gives the paths a ridge to follow
/// (`params.ridge_weight`): capped at [`RIDGE_CAP`] times the level, the kept prior's voxels at
/// the cap. The nodes in the extracted solid and outside the prior's voxels are then centred
/// (`centring`): on the extracted surface ([`centre_nodes`]: at most a voxel, in vessels up to
/// four voxels wide) or, where the paths follow the ridges, on the ridge of `relative`
/// ([`centre_on_ridge`]: at most [`RIDGE_SHIFT_VOXELS`]).
#[allow(clippy::too_many_arguments)]
pub fn completed_centreline(
    extracted: SolidPart,
    prior: Option<SolidPart>,
    prior_kept: bool,
    params: &SkeletonParams,
    centring: Centring,
    working_voxel_mm: f64,
    bridges: Option<&Volume<u8>>,
    relative: Option<&Volume<f32>>,
) -> VesselTree {
    let kept_prior = prior.filter(|_| prior_kept);
    let solid = Volume {
        data: (0..extracted.voxels.data.len())
            .map(|i| {
                let set = |v: Option<&Volume<u8>>| v.is_some_and(|v| v.data[i] != 0);
                (extracted.voxels.data[i] != 0 || set(kept_prior.map(|p| p.voxels)) || set(bridges)) as u8
            })
            .collect(),
        ..extracted.voxels.clone()
    };
    let followed = relative.filter(|r| params.ridge_weight > 0.0 && r.data.len() == solid.data.len());
    let ridge: Option<Vec<f32>> = followed.map(|r| {
        r.data
            .iter()
            .enumerate()
            .map(|(i, &d)| {
                let in_prior = kept_prior.is_some_and(|p| p.voxels.data[i] != 0);
                if in_prior { 1.0 } else { d.clamp(0.0, RIDGE_CAP) / RIDGE_CAP }
            })
            .collect()
    });
    let mut tree = skeletonize_along(&solid, ridge.as_deref(), params);
    let h = solid.grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    let extracted_index = SurfaceIndex::new(extracted.surface);
    let movable = |p: DVec3| {
        // Nodes of the extracted solid outside the prior's voxels.
        extracted.voxels.is_set_at(p) && prior.is_none_or(|part| !part.voxels.is_set_at(p))
    };
    match (centring, followed) {
        (Centring::Off, _) => {}
        (Centring::Ridge, Some(field)) => centre_on_ridge(&mut tree, field, movable, RIDGE_SHIFT_VOXELS * h),
        // In vessels up to 4 voxels wide.
        (Centring::Surface | Centring::Ridge, _) => centre_nodes(&mut tree, &extracted_index, movable, h, 4.0 * h),
    }
    let prior_index = prior.map(|p| (p, SurfaceIndex::new(p.surface)));
    let depths: Vec<(f64, f64, f64)> = tree
        .nodes
        .par_iter()
        .map(|n| {
            let p = n.position_mm;
            let in_extracted = extracted.depth(&extracted_index, p);
            // (depth in the prior when it is part of the solid, distance to it from outside)
            let (in_prior, to_prior) = match &prior_index {
                Some((part, index)) => match (part.voxels.is_set_at(p), prior_kept) {
                    (true, true) => (index.distance(p), 0.0),
                    (true, false) => (0.0, 0.0),
                    (false, _) => (0.0, index.distance(p)),
                },
                None => (0.0, f64::INFINITY),
            };
            (in_extracted, in_prior, to_prior)
        })
        .collect();
    for (n, (in_extracted, in_prior, to_prior)) in tree.nodes.iter_mut().zip(depths) {
        n.radius_mm = n.radius_mm.max(0.5 * working_voxel_mm);
        let depth = in_extracted.max(in_prior);
        if depth > n.radius_mm && depth <= n.radius_mm + h {
            n.radius_mm = depth;
        }
        n.kind = if to_prior <= h.max(working_voxel_mm) { KIND_PRIOR_VESSEL } else { KIND_NEW_VESSEL };
    }
    tree
}

/// Writes `centreline.swc`, `centreline.vtp` (with each node's `Confidence`), `branches.csv`
/// and `confidence.png` (new branches coloured by confidence, [`branch_confidence`] in `views`),
/// and with a true tree scores the centreline, by confidence bin too, and draws
/// `centreline.png` (true missing vessels found / missed, false new branches). New branches of
/// confidence below `min_confidence`, or with `arrival` of arrival agreement below its minimum
/// ([`crate::output::arrival`]), are left out of the written and scored centreline (not of
/// `branches.csv`). Returns the summary and every node's confidence (of `tree`, all branches).
pub fn write_centreline(
    dir: &Path,
    all: &VesselTree,
    views: &[ConeBeamView],
    truth: Option<(&[Segment], &[Segment])>,
    min_confidence: f64,
    arrival: Option<ArrivalCheck<'_>>,
) -> Result<(CentrelineSummary, Vec<f64>)> {
    let branches = branch_confidence(all, views);
    let all_confidence = node_confidence(all, &branches);
    let agreement = match &arrival {
        Some(a) => arrival_agreement(all, &branches, views, a.maps, a.tolerance_frames as f32, a.exit_px),
        None => vec![None; branches.len()],
    };
    write_branches_csv(&dir.join("branches.csv"), &branches, views.len(), &agreement)?;
    let min_agreement = arrival.as_ref().map_or(0.0, |a| a.min_agreement);
    let drop: Vec<bool> = branches
        .iter()
        .zip(&agreement)
        .map(|(b, a)| b.new && (b.confidence < min_confidence || a.is_some_and(|a| a < min_agreement)))
        .collect();
    let kept;
    let (tree, confidence) = if drop.contains(&true) {
        kept = without_branches(all, &branches, &drop, &all_confidence);
        (&kept.0, &kept.1)
    } else {
        (all, &all_confidence)
    };
    let header = format!(
        "ctadsa completed centreline: positions and radii in mm (world coordinates of the case)\n\
         type {KIND_PRIOR_VESSEL} = vessel of the prior (CTA), type {KIND_NEW_VESSEL} = new vessel found from the views"
    );
    write_swc(&dir.join("centreline.swc"), tree, &header)?;
    write_vtp(&dir.join("centreline.vtp"), tree, &[("Confidence", confidence)])?;
    let segments = tree.segments();
    draw_confidence(&dir.join("confidence.png"), &segments, tree, confidence)?;
    let length_mm = segments.iter().map(Segment::length_mm).sum();
    let new_length_mm =
        segments.iter().filter(|s| tree.nodes[s.child].kind == KIND_NEW_VESSEL).map(Segment::length_mm).sum();
    let (scores, confidence_bins) = match truth {
        Some((missing, whole)) if !missing.is_empty() => {
            let (scores, verdicts) = score_centreline(tree, missing, whole);
            draw_verdicts(&dir.join("centreline.png"), &segments, missing, &verdicts)?;
            let pieces = verdicts
                .new_segments
                .iter()
                .zip(&verdicts.new_true_length_mm)
                .map(|(s, &t)| (confidence[s.child], s.length_mm(), Some(t)));
            (Some(scores), confidence_bins(pieces))
        }
        _ => {
            let new = segments.iter().filter(|s| tree.nodes[s.child].kind == KIND_NEW_VESSEL);
            (None, confidence_bins(new.map(|s| (confidence[s.child], s.length_mm(), None))))
        }
    };
    let kept_new = branches.iter().zip(&drop).filter(|(b, d)| b.new && !**d).count();
    let arrival_dropped = arrival.is_some().then(|| drop.iter().zip(&branches).filter(|(d, b)| **d && b.new).count());
    let summary = CentrelineSummary {
        nodes: tree.nodes.len(),
        length_mm,
        new_length_mm,
        scores,
        branches: branches.len() - branches.iter().filter(|b| b.new).count() + kept_new,
        new_branches: kept_new,
        confidence_bins,
        arrival_dropped_branches: arrival_dropped,
    };
    Ok((summary, all_confidence))
}

/// `confidence.png`: the prior's centreline in grey, the new branches coloured by confidence
/// ([`confidence_rgb`], one colour per bin); four views.
fn draw_confidence(path: &Path, segments: &[Segment], tree: &VesselTree, confidence: &[f64]) -> Result<()> {
    let prior: Vec<Segment> =
        segments.iter().filter(|s| tree.nodes[s.child].kind != KIND_NEW_VESSEL).copied().collect();
    let context = segment_tubes(&prior, 0.15, 5);
    let bins: Vec<TriMesh> = (0..CONFIDENCE_BINS)
        .map(|k| {
            let in_bin: Vec<Segment> = segments
                .iter()
                .filter(|s| tree.nodes[s.child].kind == KIND_NEW_VESSEL && bin_of(confidence[s.child]) == k)
                .copied()
                .collect();
            segment_tubes(&in_bin, 0.3, 6)
        })
        .collect();
    let mut parts = vec![Coloured { mesh: &context, rgb: CONTEXT_RGB }];
    for (k, mesh) in bins.iter().enumerate() {
        parts.push(Coloured { mesh, rgb: confidence_rgb((k as f64 + 0.5) / CONFIDENCE_BINS as f64) });
    }
    let mut views = standard_views(320);
    views.push(OrbitView { azimuth_deg: 0.0, elevation_deg: 89.0, width: 320, height: 320 });
    write_mesh_png(path, &parts, &views)
}

/// Colours of `centreline.png`.
pub const FOUND_RGB: [u8; 3] = [40, 160, 70];
pub const MISSED_RGB: [u8; 3] = [235, 140, 20];
pub const FALSE_RGB: [u8; 3] = [200, 40, 200];
const CONTEXT_RGB: [u8; 3] = [170, 170, 170];

/// The predicted centreline in grey, true missing vessels green where found and orange where
/// missed, new branches on no true vessel magenta; four views.
fn draw_verdicts(path: &Path, predicted: &[Segment], missing: &[Segment], verdicts: &CentrelineMatch) -> Result<()> {
    let pick = |segments: &[Segment], keep: &[bool], want: bool| -> Vec<Segment> {
        segments.iter().zip(keep).filter(|(_, k)| **k == want).map(|(s, _)| *s).collect()
    };
    let found = segment_tubes(&pick(missing, &verdicts.missing_found, true), 0.3, 6);
    let missed = segment_tubes(&pick(missing, &verdicts.missing_found, false), 0.3, 6);
    let false_new = segment_tubes(&pick(&verdicts.new_segments, &verdicts.new_true, false), 0.3, 6);
    let context = segment_tubes(predicted, 0.15, 5);
    let mut views = standard_views(320);
    views.push(OrbitView { azimuth_deg: 0.0, elevation_deg: 89.0, width: 320, height: 320 });
    write_mesh_png(
        path,
        &[
            Coloured { mesh: &context, rgb: CONTEXT_RGB },
            Coloured { mesh: &found, rgb: FOUND_RGB },
            Coloured { mesh: &missed, rgb: MISSED_RGB },
            Coloured { mesh: &false_new, rgb: FALSE_RGB },
        ],
        &views,
    )
}
