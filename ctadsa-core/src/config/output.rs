//! `[output]`: extraction level, mesh, centreline and metrics.

use serde::{Deserialize, Serialize};

/// `[output]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Iso-level of the completed surface as a fraction of the density volume's 99.9th
    /// percentile (`mc_relative = true`) or in density units.
    pub mc_level: f64,
    pub mc_relative: bool,
    /// Voxel of the output density volume (mm); 0 = the case's working voxel.
    pub voxel_mm: f64,
    /// Mesh format: obj, ply or stl.
    pub mesh_format: String,
    /// Surface samples for metrics.
    pub metric_samples: usize,
    /// Connected components of the extracted surface with less area than this (mm²) are
    /// dropped (floaters); 0 keeps everything. The unfiltered surface is kept as `mesh-raw.*`.
    pub min_island_mm2: f64,
    /// Pick the iso-level from the views (`docs/METRICS.md`): the level whose extracted
    /// volume, projected into every view, best matches the views' vessel masks. `mc_level` is
    /// then ignored.
    pub level_from_views: bool,
    /// Vessel-mask threshold of the views' masks that `level_from_views` matches (fraction of
    /// the view's 99.5th percentile, as `init.mask_threshold`); 0 = `init.mask_threshold`.
    pub level_mask_threshold: f64,
    /// `level_mask_threshold` for runs of two views or fewer (0 = the same). Two views leave
    /// the depth of a vessel open where the back-projections of different vessels cross, and
    /// the faint density the training puts there is the least reliable: the level is matched to
    /// the brighter vessel pixels. 0.07 made the completion beat the untouched prior overall on
    /// all 8 BraVa trees with 2 views (0.05: 4 of 8; docs/RESULTS.md).
    pub level_mask_threshold_two_views: f64,
    /// Keep the prior: the completed surface is the prior mesh joined with the extracted
    /// surface's new vessels (its parts outside the prior and farther than `keep_prior_mm`
    /// from it).
    pub keep_prior: bool,
    /// See `keep_prior` (mm). 0.3 scored best of 0.3 and 1.0 on the BraVa trees
    /// (docs/RESULTS.md).
    pub keep_prior_mm: f64,
    /// Keep only the pieces of the extracted surface that the density links to the prior:
    /// a connected component is kept when most of its vertices lie next to voxels joined to
    /// the prior by a path of density ≥ this fraction × the iso-level (26-connected). 0 = off.
    /// Needs a prior.
    pub connected_level_fraction: f64,
    /// Faint vessels at their own scale (`docs/RESULTS.md`): with `level_from_views`, a second,
    /// lower level is picked the same way from the views' masks at this threshold, and the
    /// level is lowered locally towards it where the density's local maximum (within
    /// `faint_radius_mm`) is low: the surface is cut at `faint_fraction` × that maximum,
    /// between the two levels. 0 = off. 0.02 / 0.7 / 1 mm scored best of the five settings
    /// measured (docs/results/earlier-2026-11.md, "Faint vessels at their own level").
    pub faint_mask_threshold: f64,
    pub faint_fraction: f64,
    pub faint_radius_mm: f64,
    /// Roots of new vessels (`output::extraction::level_field`): with
    /// `level_from_views`, within `near_prior_mm` of the prior the level is the one matched to
    /// the views' masks at this threshold, where that is lower than the level (0 = off). With
    /// two views (level masks at 0.07) 0.05 within 2 mm lowered CD_ROI and HD95_ROI on 8 of 8
    /// BraVa trees (512²) and the false surface with them; the same threshold everywhere grows
    /// ghosts far from the prior (docs/results/settings-2026-11.md, "Two views: seed reach, what training
    /// keeps, and the iso-level").
    pub near_prior_mask_threshold: f64,
    pub near_prior_mm: f64,
    /// Centreline (`centreline.swc` / `.vtp`, TEASAR on the completed solid): each traced
    /// path covers the voxels within `centreline_scale` × the vessel radius +
    /// `centreline_const_mm` of it (larger: fewer, longer branches).
    pub centreline_scale: f64,
    pub centreline_const_mm: f64,
    /// `centreline_const_mm` for runs of two views or fewer (absent: the same). With two
    /// views many new pieces are doubles beside a found vessel or stubs leaving the prior at
    /// the wrong place; a wider cover traces fewer of them. 2.0 (with
    /// `centreline_bridge_fraction_two_views = 0.5`) kept the 2-view recall of the missing
    /// centreline and raised its precision by 1.9–2.4 points on the 8 BraVa trees, on each of
    /// three seed pairs (docs/RESULTS.md, "Two views: where the centreline loses").
    pub centreline_const_mm_two_views: Option<f64>,
    /// `centreline_const_mm` for two-view runs whose new branches are checked against the
    /// case's arrival maps (`arrival_min_agreement` > 0 and maps for both views; absent:
    /// `centreline_const_mm_two_views`): the check leaves out the ghosts that the wider cover
    /// was for, so a narrower one traces more of the missing vessels.
    pub centreline_const_mm_arrival: Option<f64>,
    /// Terminal centreline branches shorter than this are removed (mm).
    pub centreline_min_branch_mm: f64,
    /// How much the traced paths follow the ridges of the density rather than the middle of
    /// the solid, in [0, 1] (0: the medial axis alone, TEASAR's penalty on the boundary
    /// distance; 1: the density alone). Where the level merges a vessel with a neighbour the
    /// medial axis runs between the two; the density's ridge runs along one of them
    /// ([`crate::data::volume::skeleton`]).
    pub centreline_ridge_weight: f64,
    /// `centreline_ridge_weight` for runs of two views or fewer (absent: the same), leaving
    /// three-view runs as they are. On two-view runs without arrival maps (8 BraVa trees, two
    /// seed pairs) 0.5 finds 0.9 points more of the missing centreline for 0.0–0.3 points of
    /// precision, and with `centreline_const_mm_two_views` 2.0 → 2.1 mm more of both
    /// (docs/RESULTS.md, "Nodes centred on the ridge").
    pub centreline_ridge_weight_two_views: Option<f64>,
    /// `centreline_ridge_weight` for two-view runs whose new branches are checked against the
    /// case's arrival maps (as `centreline_const_mm_arrival`; absent:
    /// `centreline_ridge_weight_two_views`).
    pub centreline_ridge_weight_arrival: Option<f64>,
    /// Centre the new vessels' centreline nodes on the extracted surface (sub-voxel:
    /// `output::centring`) before their radii are measured. On by default: on the 8 BraVa
    /// trees (3 views, 512²) centreline recall and precision rose on every tree and the radius
    /// error fell from 0.096 to 0.081 mm (docs/RESULTS.md, "The centreline graph").
    pub centreline_centring: bool,
    /// Where a run's paths follow the density's ridges (its ridge weight > 0), centre the nodes
    /// on the ridge across their branch (`output::centring::centre_on_ridge`) rather than on
    /// the surface's chord: where the level merges a vessel with a fainter neighbour the
    /// chord's middle lies between the two (docs/RESULTS.md, "Paths along the ridges").
    pub centreline_ridge_centring: bool,
    /// Voxel (mm) of the grid the centreline is traced on; 0 = the density volume's. A finer
    /// grid keeps vessels thinner than the working voxel whole: the completion's density is
    /// voxelised again at this size, cut at the same iso-level, and skeletonised (the surface,
    /// the mesh and its scores stay on the density volume's grid). Nodes within the coarser
    /// of the two voxels of the prior stay prior vessels, and the smallest component kept
    /// holds the same volume.
    pub centreline_voxel_mm: f64,
    /// Beads joined (0 = off): the centreline is traced through the voxels of density ≥ this
    /// fraction × the surface's level that lie within `centreline_bridge_mm` of the extracted
    /// solid and connect to it, so that a thin vessel the level cuts into beads gives one
    /// branch instead of none. The surface is not changed.
    pub centreline_bridge_fraction: f64,
    /// `centreline_bridge_fraction` for runs of two views or fewer (absent: the same).
    pub centreline_bridge_fraction_two_views: Option<f64>,
    pub centreline_bridge_mm: f64,
    /// No bridge voxel lies within this distance (mm) of the prior's voxels (0 = no clearance):
    /// next to the prior the bridges join spurs and ghosts more than vessels (8 BraVa trees,
    /// 3 views: 2 mm raised the centreline's precision from 83.0 to 86.0 % for 1.1 points of
    /// recall; docs/RESULTS.md, "The centreline graph").
    pub centreline_bridge_prior_clearance_mm: f64,
    /// New vessels of lower confidence (`output::confidence`, in [0, 1]) are left out of the
    /// centreline and the mesh (`mesh-confidence.ply` and `branches.csv` keep them); 0 keeps
    /// everything. docs/RESULTS.md, "Which new vessels to trust", gives the precision / recall
    /// trade-off.
    pub min_confidence: f64,
    /// With two views whose arrival maps the case has (a time-resolved run,
    /// [`crate::data::case::ViewEntry::arrival`]): new branches of which less than this share of
    /// the length fills in the same frame in both views are left out of the written and scored
    /// centreline, as ghosts ([`crate::output::arrival`]); 0 keeps them.
    pub arrival_min_agreement: f64,
    /// Frames by which the two views' arrivals may lie apart and still agree
    /// ([`crate::method::arrival::frames_agree`]; 0: the spans their frames stand for overlap).
    pub arrival_tolerance_frames: f64,
    /// With `arrival_min_agreement`: the branches are checked on maps that hide the prior's
    /// projection, a view the prior hides at a point judged by the frames filled within this
    /// many pixels of it, outside the projection ([`crate::method::arrival::frames_seen`]; 0:
    /// that view cannot tell). Absent: on the maps as they are, where the prior shows its own
    /// frame.
    pub arrival_prior_exit_px: Option<u32>,
}

impl OutputConfig {
    /// The vessel-mask threshold the iso-level is matched to for a run of `views` views, given
    /// the seeds' `init_mask_threshold` (see `level_mask_threshold` and
    /// `level_mask_threshold_two_views`).
    pub fn level_mask_threshold_for(&self, views: usize, init_mask_threshold: f64) -> f64 {
        let general = if self.level_mask_threshold > 0.0 { self.level_mask_threshold } else { init_mask_threshold };
        if views <= 2 && self.level_mask_threshold_two_views > 0.0 {
            self.level_mask_threshold_two_views
        } else {
            general
        }
    }

    /// The centreline's cover constant (mm) for a run of `views` views (`centreline_const_mm`,
    /// `centreline_const_mm_two_views`; `centreline_const_mm_arrival` when `arrival_checked`:
    /// two views whose new branches the arrival maps check).
    pub fn centreline_const_mm_for(&self, views: usize, arrival_checked: bool) -> f64 {
        let two_views = self.centreline_const_mm_two_views.filter(|_| views <= 2).unwrap_or(self.centreline_const_mm);
        self.centreline_const_mm_arrival.filter(|_| arrival_checked && views == 2).unwrap_or(two_views)
    }

    /// The ridge weight of the centreline's paths for a run of `views` views
    /// (`centreline_ridge_weight`, `centreline_ridge_weight_two_views`;
    /// `centreline_ridge_weight_arrival` when `arrival_checked`, as
    /// [`Self::centreline_const_mm_for`]).
    pub fn centreline_ridge_weight_for(&self, views: usize, arrival_checked: bool) -> f64 {
        let two_views =
            self.centreline_ridge_weight_two_views.filter(|_| views <= 2).unwrap_or(self.centreline_ridge_weight);
        self.centreline_ridge_weight_arrival.filter(|_| arrival_checked && views == 2).unwrap_or(two_views)
    }

    /// Whether some run's centreline follows the density's ridges.
    pub fn centreline_follows_ridges(&self) -> bool {
        let positive = |w: Option<f64>| w.is_some_and(|w| w > 0.0);
        self.centreline_ridge_weight > 0.0
            || positive(self.centreline_ridge_weight_two_views)
            || positive(self.centreline_ridge_weight_arrival)
    }

    /// The bead-joining fraction for a run of `views` views (`centreline_bridge_fraction`,
    /// `centreline_bridge_fraction_two_views`).
    pub fn centreline_bridge_fraction_for(&self, views: usize) -> f64 {
        self.centreline_bridge_fraction_two_views.filter(|_| views <= 2).unwrap_or(self.centreline_bridge_fraction)
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            mc_level: 0.25,
            mc_relative: true,
            voxel_mm: 0.0,
            mesh_format: "obj".into(),
            metric_samples: 50_000,
            min_island_mm2: 0.0,
            level_mask_threshold: 0.0,
            level_mask_threshold_two_views: 0.07,
            level_from_views: true,
            keep_prior: true,
            keep_prior_mm: 0.3,
            connected_level_fraction: 0.0,
            faint_mask_threshold: 0.02,
            faint_fraction: 0.7,
            faint_radius_mm: 1.0,
            near_prior_mask_threshold: 0.0,
            near_prior_mm: 2.0,
            centreline_scale: 1.5,
            centreline_const_mm: 1.0,
            centreline_const_mm_two_views: None,
            centreline_const_mm_arrival: None,
            centreline_min_branch_mm: 1.0,
            centreline_ridge_weight: 0.0,
            centreline_ridge_weight_two_views: None,
            centreline_ridge_weight_arrival: None,
            centreline_centring: true,
            centreline_ridge_centring: true,
            centreline_voxel_mm: 0.0,
            centreline_bridge_fraction: 0.0,
            centreline_bridge_fraction_two_views: None,
            centreline_bridge_mm: 1.0,
            centreline_bridge_prior_clearance_mm: 0.0,
            min_confidence: 0.0,
            arrival_min_agreement: 0.5,
            arrival_tolerance_frames: 0.0,
            arrival_prior_exit_px: None,
        }
    }
}
