//! `[init]`: the Gaussians on the prior (N1) and the image seeds (N2).

use serde::{Deserialize, Serialize};

/// How the N2 seeds are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SeedMode {
    /// Residual (vessel mask minus the dilated prior projection) back-projected, supported in
    /// every view, outside the prior (the method).
    ResidualIntersect,
    /// Residual back-projection summed over views, no intersection (ablation).
    ResidualUnion,
    /// Uniform random points in the working box outside the prior (ablation).
    Uniform,
    /// Vessel masks (not residuals) back-projected and intersected; no prior needed
    /// (R²-Gaussian-like baseline).
    AllViewsIntersect,
    /// No N2 seeds (prior only).
    None,
}

/// `[init]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InitConfig {
    /// Gaussians sampled on the prior surface.
    pub n1: usize,
    /// Gaussians seeded from the images.
    pub n2: usize,
    pub n2_mode: SeedMode,
    /// Vessel mask: pixels ≥ this × the 99.5th percentile of the view's positive pixels, and
    /// at least 3 × the view's estimated noise σ (`data::masks::vessel_level`; no floor on a
    /// noise-free view).
    pub mask_threshold: f64,
    /// Dilation (pixels) of the projected prior before it is subtracted. It covers the
    /// silhouette's rasterisation error; every pixel more hides the vessels that leave the prior
    /// or pass behind it. On the BraVa cases (256² views) 1 px beat 2 px on all 8 trees with 3
    /// views, and 0 px seeded halos around the prior (docs/RESULTS.md).
    pub prior_dilation_px: u32,
    /// Residual seeds: the prior's projection is subtracted from each view instead of masked.
    /// A pixel shows residual where the image minus the prior mesh's chord length (the longest
    /// within `prior_dilation_px`) × the view's fitted contrast per mm exceeds the vessel level,
    /// and that difference scores the voxel (`data::masks::minus_solid`); off: a pixel in the
    /// prior's dilated projection shows none, and a vessel behind the prior in any view is never
    /// seeded. On the 8 BraVa trees (512² views, 3 views) it cuts the ghosts among the seeds
    /// from 27 to 19 % and lowers CD_ROI on 13 of 16 runs over two seeds (docs/results/settings-2026-11.md,
    /// "The prior subtracted, not masked").
    pub subtract_prior: bool,
    /// With `subtract_prior`: the prior's chords are those of its mesh moved outward by the
    /// offset (0–0.4 mm), and blurred by the Gaussian (0–2 px), that best explain each view on
    /// the prior's footprint, fitted with the contrast (`data::projector::matched`), before they are
    /// dilated and subtracted. The mesh, an iso-surface, lies inside the imaged vessel's edge:
    /// its sharp chords leave a ring along every edge and thin vessel that a dilation of the
    /// projection (`prior_dilation_px`) covers, hiding what passes behind the prior with it.
    pub fit_prior_projection: bool,
    /// Dilation (pixels) of the residual masks before back-projection.
    pub residual_dilation_px: u32,
    /// Voxel of the back-projection grid (mm); 0 = the case's working voxel.
    pub n2_voxel_mm: f64,
    /// Neighbours for the initial isotropic scale.
    pub knn: usize,
    /// Residual seeds (intersect modes): a view whose pixel lies in the prior's dilated
    /// projection cannot show residual there, so it supports the voxel when its vessel mask
    /// does, provided at least half of the views (rounded up) show residual, and (with
    /// `occluded_connected`) the voxel connects to a fully supported one or to the prior. Off:
    /// every view must show residual (the vessels behind the prior in any view are never
    /// seeded). Applies to runs with at least `occluded_min_views` views. Off by default: with
    /// the quick configuration's 30,000 prior Gaussians it is worse on every BraVa tree with 3
    /// views (CD_ROI 1.91 → 2.38 mm, HD95_ROI 5.71 → 6.79; docs/RESULTS.md).
    pub occluded_views_support: bool,
    /// With `occluded_views_support`: a voxel that a view passed only because the prior hides
    /// it is kept only when its 26-connected group of supported voxels holds a voxel that every
    /// view supports with residual, or comes within `connected_to_prior_mm` of the prior.
    pub occluded_connected: bool,
    /// Apply `occluded_views_support` only to runs with at least this many views.
    pub occluded_min_views: usize,
    /// Where `connected_to_prior_mm` applies (runs of at most `connected_max_views` views):
    /// instead of keeping every group of supported voxels that comes that close to the prior,
    /// grow from those voxels, nearest the prior first, at most this far (mm of path), each
    /// view's pixel claimed by the first voxel that reaches it (`crate::method::seed_growth`:
    /// a ghost, where two vessels' back-projections cross, finds its pixels taken by the vessels
    /// grown along their length). The seeds are then `grow_claims_n2` of the grown voxels, at
    /// least `grow_claims_spacing_mm` apart, instead of `n2` and `seed_spacing_mm`. 0 = off:
    /// on the 8 BraVa trees with 2 views it halves the ghosts among the seeds and seeds a third
    /// more of the missing centreline, and leaves the trained result within the run-to-run
    /// spread (docs/results/settings-2026-11.md, "Two views: what the seeds change").
    pub grow_claims_mm: f64,
    /// Image seeds with `grow_claims_mm` (at most).
    pub grow_claims_n2: usize,
    /// Spacing (mm) of the image seeds with `grow_claims_mm`.
    pub grow_claims_spacing_mm: f64,
    /// Keep only seeds in connected groups of supported voxels that come within this distance
    /// (mm) of the prior: a vessel tree is connected, while the intersections of two views'
    /// back-projections ("ghosts") float free. 0 = off. Measured on the 8 BraVa trees
    /// (docs/RESULTS.md): it helps with 2 views and hurts with 3, where the third view already
    /// rejects the ghosts and the filter drops true vessels whose junction the residual hides.
    pub connected_to_prior_mm: f64,
    /// Apply `connected_to_prior_mm` only to runs with at most this many views.
    pub connected_max_views: usize,
    /// Image seeds at least this far apart (mm), the best-scored first: spreads `n2` along every
    /// supported vessel instead of piling it on the brightest. 0 = the `n2` best-scored voxels.
    /// Re-seeding (`densify.reseed_at`) spaces its seeds the same way.
    pub seed_spacing_mm: f64,
    /// `n2` for runs of two views or fewer (absent: `n2`). Two views' back-projections cross
    /// in ghosts wherever two vessels share a detector row, and more seeds seed more of them:
    /// on the 8 BraVa trees (512² views) 20,000 seeds 1 mm apart raised CD_ROI with 2 views by
    /// 0.25 mm (worse on 4 of 4 trees) while 10,000 seeds 0.7 mm apart left it level with 3
    /// views (docs/results/settings-2026-11.md, "Denser image seeds with three views").
    pub n2_two_views: Option<usize>,
    /// `seed_spacing_mm` for runs of two views or fewer (absent: `seed_spacing_mm`).
    pub seed_spacing_mm_two_views: Option<f64>,
    /// Runs of at most this many views add image seeds every 0.5 mm along the vessels tracked
    /// from the prior through the views' residuals (`crate::method::tracking`: a track follows
    /// the direction both views show best, with a cost for a turn either view sees and for a
    /// change of either view's brightness, and stops on pixels another track claimed at another
    /// depth). Residual intersect modes with a prior only. 0 = off.
    pub track_max_views: usize,
    /// A track goes on while the smaller of the views' residuals over its look-ahead, over the
    /// vessel level, averages at least this (less its costs).
    pub track_level: f64,
    /// Tracks start at supported voxels at most this far (mm) from the prior (next to it the
    /// subtracted residual is weakest).
    pub track_start_mm: f64,
    /// A direction's score loses this per unit of 1 − cos of the largest turn a view sees.
    pub track_turn_cost: f64,
    /// A direction's score loses this per unit of |ln| change of a view's brightness from the
    /// track's so far.
    pub track_brightness_cost: f64,
    /// A track ends after this long (mm) on pixels another track claimed at another depth
    /// (a pixel shows one vessel at one depth); 0 = no claims.
    pub track_claimed_run_mm: f64,
    /// Most tracked seeds (all tracks together).
    pub track_max_points: usize,
    /// Rounds of tracking: the first starts beside the prior, each further one beside the
    /// tracks of the round before (the branches of new vessels, which never touch the prior).
    pub track_rounds: usize,
    /// `track_max_points` for runs whose tracks' claims the arrival maps check
    /// (`arrival_track_claims` with two views and the case's maps; absent: `track_max_points`).
    pub track_max_points_arrival: Option<usize>,
    /// `track_rounds` for the same runs (absent: `track_rounds`): their tracks go farther.
    /// Six rounds and 80,000 points instead of four and 60,000, quick-512: never seeded lower
    /// on 8 of 8 shared and 8 of 8 held-out BraVa trees, CD_ROI on 7 and 5 of 8
    /// (docs/RESULTS.md, "Two views: where the centreline loses").
    pub track_rounds_arrival: Option<usize>,
    /// `fit_prior_projection` for the tracker's residual (absent: as the image seeds'). The
    /// tracks and the image seeds then read two residuals, back-projected apart. Fitted and
    /// not dilated (`track_prior_dilation_px = 0`) for the tracks alone, on the 8 BraVa trees
    /// (512² views, quick-512): CD_ROI 0.84 → 0.77 mm with 3 views, 2.09 → 2.06 mm with 2 at
    /// 3 points less centreline precision (docs/results/settings-2026-11.md, "The tracks' own residual").
    pub track_fit_prior_projection: Option<bool>,
    /// `prior_dilation_px` for the tracker's residual (absent: as the image seeds').
    pub track_prior_dilation_px: Option<u32>,
    /// With two views whose arrival maps the case has (a time-resolved run,
    /// [`crate::data::case::ViewEntry::arrival`]): keep only the image seeds whose two pixels
    /// (3 × 3 around each) filled within `arrival_tolerance_frames` of each other
    /// ([`crate::method::arrival`]): the ghosts where two vessels cross fill at two times.
    pub arrival_seeds: bool,
    /// The same check for the points the tracker starts from (`track_max_views`): a track then
    /// starts only where both views fill at once.
    pub arrival_track_starts: bool,
    /// The same check for the tracks' claims (`track_claimed_run_mm`: a track stops on pixels
    /// another track claimed at another depth): a claim whose point fills at two times, a
    /// ghost's, gives way to a point that fills at once. Member-only retraining of the 2-view
    /// runs of quick-512 on 8 shared BraVa trees: CD_ROI 1.724 → 1.640 mm (8 of 8), centreline
    /// 50.3 / 68.8 → 52.2 / 68.9 % (docs/RESULTS.md, "Two views: where the centreline loses").
    pub arrival_track_claims: bool,
    /// Two views and the case's arrival maps: the re-seeds of training (`densify.reseed_at`)
    /// only where both views fill at once, as `arrival_seeds` for the image seeds.
    pub arrival_reseeds: bool,
    /// Frames by which the two views' arrivals may lie apart and still agree
    /// ([`crate::method::arrival::frames_agree`]; 0: the spans their frames stand for overlap).
    pub arrival_tolerance_frames: f64,
    /// Where the prior's projection covers a point's 3 × 3 pixels in a view, that view cannot
    /// tell the point's arrival (the prior, filling first, shows its own frame there): the seed
    /// checks above then judge it by the pixels just outside the projection
    /// (`arrival_prior_exit_px`), or let the other view's filled pixels decide alone (the new
    /// centreline branches, `output.arrival_min_agreement`, are checked on the maps as they are).
    pub arrival_prior_unknown: bool,
    /// With `arrival_prior_unknown`: a view the prior hides at a point is judged by the frames
    /// filled within this many pixels (a square) around the point's projection, outside the
    /// prior's projection, where a vessel behind the prior leaves it
    /// ([`crate::method::arrival::frames_seen`]); 0, or none filled there: it cannot tell.
    /// 6 against 0, whole 2-view runs of quick-512 on 8 shared and 8 held-out BraVa trees:
    /// CD_ROI lower on 7 of 8 of each, false surface on 8 of 8 of each (docs/RESULTS.md, "Two
    /// views: where the centreline loses").
    pub arrival_prior_exit_px: u32,
}

impl InitConfig {
    /// The number of image seeds for a run of `views` views (`n2`, `n2_two_views`).
    pub fn n2_for(&self, views: usize) -> usize {
        self.n2_two_views.filter(|_| views <= 2).unwrap_or(self.n2)
    }

    /// Whether two-view runs check seeds against the case's arrival maps (`arrival_seeds`,
    /// `arrival_track_starts`, `arrival_track_claims` or `arrival_reseeds`): the maps are then read.
    pub fn checks_arrival(&self) -> bool {
        self.arrival_seeds || self.arrival_track_starts || self.arrival_track_claims || self.arrival_reseeds
    }

    /// The most tracked seeds (`track_max_points`; `track_max_points_arrival` where
    /// `claims_checked`: the arrival maps check the tracks' claims).
    pub fn track_max_points_for(&self, claims_checked: bool) -> usize {
        self.track_max_points_arrival.filter(|_| claims_checked).unwrap_or(self.track_max_points)
    }

    /// The rounds of tracking (`track_rounds`; `track_rounds_arrival` where `claims_checked`).
    pub fn track_rounds_for(&self, claims_checked: bool) -> usize {
        self.track_rounds_arrival.filter(|_| claims_checked).unwrap_or(self.track_rounds)
    }

    /// The image seeds' spacing (mm) for a run of `views` views (`seed_spacing_mm`,
    /// `seed_spacing_mm_two_views`).
    pub fn seed_spacing_mm_for(&self, views: usize) -> f64 {
        self.seed_spacing_mm_two_views.filter(|_| views <= 2).unwrap_or(self.seed_spacing_mm)
    }
}

impl Default for InitConfig {
    fn default() -> Self {
        Self {
            n1: 30_000,
            n2: 30_000,
            n2_mode: SeedMode::ResidualIntersect,
            mask_threshold: 0.05,
            prior_dilation_px: 3,
            subtract_prior: false,
            residual_dilation_px: 1,
            fit_prior_projection: false,
            n2_voxel_mm: 0.0,
            knn: 3,
            occluded_views_support: false,
            occluded_connected: true,
            occluded_min_views: 3,
            grow_claims_mm: 0.0,
            grow_claims_n2: 20_000,
            grow_claims_spacing_mm: 0.7,
            track_max_views: 0,
            track_level: 0.3,
            track_start_mm: 1.0,
            track_turn_cost: 1.0,
            track_brightness_cost: 1.0,
            track_claimed_run_mm: 1.0,
            track_max_points: 20_000,
            track_rounds: 1,
            track_max_points_arrival: None,
            track_rounds_arrival: None,
            track_fit_prior_projection: None,
            track_prior_dilation_px: None,
            connected_to_prior_mm: 3.0,
            connected_max_views: 2,
            seed_spacing_mm: 0.0,
            n2_two_views: None,
            seed_spacing_mm_two_views: None,
            arrival_seeds: false,
            arrival_track_starts: false,
            arrival_track_claims: false,
            arrival_reseeds: false,
            arrival_tolerance_frames: 0.0,
            arrival_prior_unknown: false,
            arrival_prior_exit_px: 0,
        }
    }
}
