//! The TOML configuration of a completion run. Every section and key has a default (the
//! paper's values where the paper gives one); unknown keys and out-of-range values are errors
//! that name the key. `--set section.key=value` overrides are applied to the TOML tree before
//! it is read, so they are checked the same way.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result, read_file};
pub use ctadsa_ops::hash_grid::HashGridConfig;

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

/// `[run]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    pub iterations: usize,
    pub seed: u64,
    /// Views rendered per step: 0 = all, n = n random views.
    pub views_per_step: usize,
    /// Checkpoint every this many iterations (0 = only at the end).
    pub checkpoint_every: usize,
    /// Detector binning applied to the case's images and views (1 = native).
    pub image_binning: u32,
    /// Use only these views of the case (indices; empty = all).
    pub views: Vec<usize>,
    /// Where the working box comes from.
    pub working_box: WorkingBoxSource,
    /// Also train a member from the prior alone (this configuration with `init.n2 = 0`) and
    /// extract the surface from the mean of the two density fields. The image seeds put density
    /// on the missing vessels and, with few views, also at crossings of different vessels'
    /// back-projections (ghosts); the prior-only member grows vessels out of the prior only, so
    /// in the mean the ghosts fall under the level while what both find stays. Doubles the
    /// training time. Ignored when the run has no image seeds or no Gaussians on the prior.
    pub prior_only_member: bool,
    /// Seeds of further image-seeded members: each is this configuration trained with that
    /// `run.seed` (its field's weights, its image seeds' draw and its views' order change), in
    /// `seed-member-<seed>/`. The image-seeded models' densities are averaged first, then with the
    /// prior-only member's (when there is one): a ghost that one model grows and the others do
    /// not falls to a fraction of its density, while what every model finds stays. Each member
    /// adds one run's training time. At most 8, none equal to `run.seed` or to each other.
    pub member_seeds: Vec<u64>,
    /// Runs of at most this many views seed the prior-only member along the vessels tracked
    /// from the prior as well (`init.track_*`, [`crate::method::tracking`]; its only image
    /// seeds): a track follows a vessel out of the tree and rarely a ghost, so the member finds
    /// more of the missing vessels while, in the mean, the image-seeded models' ghosts still
    /// fall to half their density. 0 = the member has no image seeds.
    pub member_tracks_max_views: usize,
    /// The prior-only member stops after this many steps of the run's schedule (its learning
    /// rates, densification and loss terms keep the run's steps); 0 = `run.iterations`. Trained
    /// as long as a long run's image-seeded models, the member fits the views with its own seeds
    /// and lays down false surface (docs/RESULTS.md, "`configs/paper.toml`").
    pub member_iterations: usize,
    /// Where this configuration's training stops when it is a member's: set by
    /// [`Config::prior_only_member`] from `run.member_iterations`; `None` = `run.iterations`.
    #[serde(skip)]
    pub stop_after: Option<usize>,
}

impl RunConfig {
    /// The step the training loop runs to: `stop_after` when set (at most `iterations`),
    /// otherwise `iterations`.
    pub fn steps_to_train(&self) -> usize {
        self.stop_after.map_or(self.iterations, |n| n.min(self.iterations))
    }
}

/// Where the reconstruction's working box comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WorkingBoxSource {
    /// The vessels' visual hull in the views joined with the prior's box, + 2 mm (default).
    Inputs,
    /// The box `case.json` declares (for a synthetic case: the complete tree's box + 1 mm).
    Case,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            iterations: 30_000,
            seed: 42,
            views_per_step: 1,
            checkpoint_every: 5000,
            image_binning: 1,
            views: vec![],
            working_box: WorkingBoxSource::Inputs,
            prior_only_member: false,
            member_seeds: vec![],
            member_tracks_max_views: 0,
            member_iterations: 0,
            stop_after: None,
        }
    }
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
    /// Vessel mask: pixels ≥ this × the 99.5th percentile of the view's positive pixels.
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
    /// from 27 to 19 % and lowers CD_ROI on 13 of 16 runs over two seeds (docs/RESULTS.md,
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
    /// spread (docs/RESULTS.md, "Two views: what the seeds change").
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
    /// views (docs/RESULTS.md, "Denser image seeds with three views").
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
    /// `fit_prior_projection` for the tracker's residual (absent: as the image seeds'). The
    /// tracks and the image seeds then read two residuals, back-projected apart. Fitted and
    /// not dilated (`track_prior_dilation_px = 0`) for the tracks alone, on the 8 BraVa trees
    /// (512² views, quick-512): CD_ROI 0.84 → 0.77 mm with 3 views, 2.09 → 2.06 mm with 2 at
    /// 3 points less centreline precision (docs/RESULTS.md, "The tracks' own residual").
    pub track_fit_prior_projection: Option<bool>,
    /// `prior_dilation_px` for the tracker's residual (absent: as the image seeds').
    pub track_prior_dilation_px: Option<u32>,
}

impl InitConfig {
    /// The number of image seeds for a run of `views` views (`n2`, `n2_two_views`).
    pub fn n2_for(&self, views: usize) -> usize {
        self.n2_two_views.filter(|_| views <= 2).unwrap_or(self.n2)
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
            track_fit_prior_projection: None,
            track_prior_dilation_px: None,
            connected_to_prior_mm: 3.0,
            connected_max_views: 2,
            seed_spacing_mm: 0.0,
            n2_two_views: None,
            seed_spacing_mm_two_views: None,
        }
    }
}

/// `[model]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Scale bounds in working-grid voxels (paper: 0.1 and 10).
    pub scale_min_voxels: f64,
    pub scale_max_voxels: f64,
    /// Footprint cut-off (standard deviations).
    pub k_sigma: f32,
    /// Initial density of every Gaussian (density units, per mm); 0 = estimated from the images.
    pub initial_density: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self { scale_min_voxels: 0.1, scale_max_voxels: 10.0, k_sigma: 3.0, initial_density: 0.0 }
    }
}

/// A learning rate decaying exponentially from `[0]` to `[1]` over the run.
pub type LrRange = [f64; 2];

/// `[optim]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Centres (mm per step; reference: 1e-4 × 200 mm).
    pub lr_means: LrRange,
    pub lr_scales: LrRange,
    pub lr_rotations: LrRange,
    pub lr_field: LrRange,
    /// Adam ε (reference 1e-15).
    pub epsilon: f64,
    /// Coupled L2 weight decay on the field (Adam's `weight_decay`; the reference's is 5e-5).
    /// 0 by default: with Adam it collapses the field to one density for every Gaussian once the
    /// image gradients are small (the paper configuration's field on BG0002 by iteration 5,000;
    /// `crate::method::field_health`, docs/RESULTS.md).
    pub field_weight_decay: f64,
    /// Which Adam: `fused` (one pass per parameter, [`ctadsa_ops::optim::FusedAdam`]) or `burn`
    /// (burn's `Adam`, the reference); the same update rule and checkpoint format.
    pub adam: AdamImpl,
}

/// Implementation of the Adam step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AdamImpl {
    #[default]
    Fused,
    Burn,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            lr_means: [0.02, 0.002],
            lr_scales: [5e-3, 5e-4],
            lr_rotations: [1e-3, 1e-4],
            lr_field: [1e-3, 1e-4],
            epsilon: 1e-15,
            field_weight_decay: 0.0,
            adam: AdamImpl::Fused,
        }
    }
}

/// `[loss]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LossConfig {
    /// λ of `(1 − λ) L1 + λ (1 − SSIM)`.
    pub lambda_dssim: f64,
    pub fn_weight: f64,
    pub fn_start: usize,
    /// Vessel pixels for the FN loss: ≥ τ × the 99.5th percentile of the target's positives.
    pub fn_tau: f64,
    pub fn_margin: f64,
    pub pa_weight: f64,
    pub pa_start: usize,
    /// Anchoring radius (mm) and neighbours.
    pub pa_radius_mm: f64,
    pub pa_k: usize,
    /// Gaussians sampled per step for the anchoring term (0 = all).
    pub pa_samples: usize,
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            lambda_dssim: 0.07,
            fn_weight: 1.5,
            fn_start: 4000,
            fn_tau: 0.01,
            fn_margin: 0.005,
            pa_weight: 0.0025,
            pa_start: 1000,
            pa_radius_mm: 0.5,
            pa_k: 8,
            pa_samples: 2048,
        }
    }
}

/// The most further image-seeded members a config may ask for (`run.member_seeds`).
pub const MAX_MEMBER_SEEDS: usize = 8;

/// The most Gaussians (or seeds, or samples) a config may ask for: far beyond the paper's
/// 500,000 cap, and small enough to fail with a message rather than an allocation abort.
pub const MAX_GAUSSIANS: usize = 20_000_000;

/// Largest number of metric samples per surface (`output.metric_samples`, `ctadsa eval
/// --samples`): a larger request is an error, not an allocation.
pub const MAX_SAMPLES: usize = 10_000_000;

/// The widest dilation (pixels) of a projected prior or residual mask a config may ask for.
pub const MAX_DILATION_PX: u32 = 64;

/// The widest field MLP a config may ask for.
pub const MAX_HIDDEN: usize = 4096;

/// `[densify]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DensifyConfig {
    pub enabled: bool,
    pub from: usize,
    pub until: usize,
    pub every: usize,
    /// Threshold on the mean NDC projected-centre gradient norm.
    pub grad_threshold: f64,
    /// Clone (not split) when max scale ≤ this × voxel; decays exponentially from the first to
    /// the second value over `[from, until]`.
    pub clone_scale_voxels: [f64; 2],
    /// Prune Gaussians with density below this.
    pub min_density: f64,
    /// Never grow beyond this many Gaussians.
    pub max_gaussians: usize,
    /// Re-seeding from what the model does not explain (`method::reseed`): at each of these
    /// iterations the views are rendered, and new Gaussians are placed where every view's
    /// residual (target − render) is bright, as the image seeds are placed at the start. The
    /// prior's pixels are not lost to it: once the model draws the prior, a vessel behind it
    /// shows in the residual. Empty = off; off as well when `enabled` is false.
    pub reseed_at: Vec<usize>,
    /// Gaussians added at each re-seeding (at most; `max_gaussians` bounds the total).
    pub reseed_n: usize,
    /// A view's residual counts where it exceeds this × the 99.5th percentile of the view's
    /// positive target pixels; 0 = `init.mask_threshold`.
    pub reseed_mask_threshold: f64,
    /// Re-seeding in runs that keep image seeds connected to the prior (`init.connected_*`):
    /// new seeds may connect to what the model already draws (the voxels of its Gaussians at
    /// least as dense as the median one) as well as to the prior, so vessels grow from their ends.
    pub reseed_from_model: bool,
    /// Re-seeding: a view whose pixel lies in the prior's dilated projection supports a voxel
    /// where its target shows a vessel, when at least half of the views show residual there (the
    /// model may draw a vessel behind the prior as a brighter prior, leaving no residual).
    pub reseed_occluded: bool,
}

impl Default for DensifyConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            from: 500,
            until: 15_000,
            every: 200,
            grad_threshold: 1e-4,
            clone_scale_voxels: [2.5, 0.5],
            min_density: 1e-6,
            max_gaussians: 500_000,
            reseed_at: Vec::new(),
            reseed_n: 1500,
            reseed_mask_threshold: 0.0,
            reseed_from_model: false,
            reseed_occluded: false,
        }
    }
}

/// The MLP's output non-linearity (both non-negative).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputActivation {
    /// `max(0, x)`, as the reference implementation (can start or get stuck at zero).
    Relu,
    /// `ln(1 + eˣ)`: strictly positive, never stuck.
    Softplus,
}

/// `[field]`: the opacity field (hash encoding + MLP).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FieldConfig {
    pub encoding: HashGridConfig,
    /// Width of the hidden layers.
    pub hidden: usize,
    /// Number of hidden layers (1–4).
    pub hidden_layers: usize,
    pub output: OutputActivation,
}

impl Default for FieldConfig {
    fn default() -> Self {
        Self { encoding: HashGridConfig::default(), hidden: 64, hidden_layers: 2, output: OutputActivation::Softplus }
    }
}

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
    /// ghosts far from the prior (docs/RESULTS.md, "Two views: seed reach, what training
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
    /// Terminal centreline branches shorter than this are removed (mm).
    pub centreline_min_branch_mm: f64,
    /// Centre the new vessels' centreline nodes on the extracted surface (sub-voxel:
    /// `output::centring`) before their radii are measured. On by default: on the 8 BraVa
    /// trees (3 views, 512²) centreline recall and precision rose on every tree and the radius
    /// error fell from 0.096 to 0.081 mm (docs/RESULTS.md, "The centreline graph").
    pub centreline_centring: bool,
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
    /// `centreline_const_mm_two_views`).
    pub fn centreline_const_mm_for(&self, views: usize) -> f64 {
        self.centreline_const_mm_two_views.filter(|_| views <= 2).unwrap_or(self.centreline_const_mm)
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
            centreline_min_branch_mm: 1.0,
            centreline_centring: true,
            centreline_voxel_mm: 0.0,
            centreline_bridge_fraction: 0.0,
            centreline_bridge_fraction_two_views: None,
            centreline_bridge_mm: 1.0,
            centreline_bridge_prior_clearance_mm: 0.0,
            min_confidence: 0.0,
        }
    }
}

/// `[pose]`: refinement of each view's pose (a small rigid correction, 6 parameters per view)
/// jointly with the Gaussians, to absorb registration error. Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseConfig {
    pub enabled: bool,
    /// First iteration at which the poses move (the Gaussians settle first).
    pub start: usize,
    /// Adam learning rate of the rotation corrections (rad), decaying from the first to the
    /// second value over the run.
    pub lr_rotation_rad: [f64; 2],
    /// Adam learning rate of the translation corrections (mm).
    pub lr_translation_mm: [f64; 2],
    /// Keep the first view fixed (the reference frame); otherwise the prior alone holds the
    /// global frame.
    pub fix_first_view: bool,
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            start: 0,
            lr_rotation_rad: [5e-4, 5e-5],
            lr_translation_mm: [0.05, 0.005],
            fix_first_view: true,
        }
    }
}

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub run: RunConfig,
    pub init: InitConfig,
    pub model: ModelConfig,
    pub field: FieldConfig,
    pub optim: OptimConfig,
    pub loss: LossConfig,
    pub densify: DensifyConfig,
    pub output: OutputConfig,
    pub pose: PoseConfig,
}

fn check(ok: bool, key: &str, what: impl std::fmt::Display) -> Result<()> {
    if ok { Ok(()) } else { Err(CoreError::invalid(format!("config key `{key}`: {what}"))) }
}

/// Parses a `--set` value: TOML syntax when it parses (numbers, booleans, arrays, quoted
/// strings), otherwise a bare string.
fn parse_value(text: &str) -> toml::Value {
    let doc = format!("v = {text}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(text.into())),
        Err(_) => toml::Value::String(text.into()),
    }
}

/// Lays `over` onto `base`: tables merge key by key, everything else replaces.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Reads a TOML file, following `base = "..."` (relative to the file, at most 8 deep).
fn load_table(path: &Path, depth: usize) -> Result<toml::Table> {
    if depth > 8 {
        return Err(CoreError::format(path, "`base` chain deeper than 8 (a cycle?)"));
    }
    let bytes = read_file(path)?;
    let text = String::from_utf8(bytes).map_err(|_| CoreError::format(path, "not UTF-8 text"))?;
    let mut table: toml::Table = text.parse().map_err(|e| CoreError::format(path, format!("invalid TOML: {e}")))?;
    match table.remove("base") {
        None => Ok(table),
        Some(toml::Value::String(b)) => {
            let base_path = path.parent().unwrap_or(Path::new(".")).join(b);
            let mut base = load_table(&base_path, depth + 1)?;
            merge(&mut base, table);
            Ok(base)
        }
        Some(_) => Err(CoreError::format(path, "`base` must be a string (a path relative to this file)")),
    }
}

/// `configs/quick.toml`, built in (the demo's and the benchmarks' configuration).
pub const QUICK_TOML: &str = include_str!("../../configs/quick.toml");

/// `configs/baselines/paper-method.toml` (the paper's method and schedule), built in: the
/// workload of the paper rows of `ctadsa bench`.
pub const PAPER_METHOD_TOML: &str = include_str!("../../configs/baselines/paper-method.toml");

impl Config {
    /// The built-in quick configuration ([`QUICK_TOML`]) with `key=value` overrides.
    pub fn quick(overrides: &[String]) -> Result<Self> {
        Self::from_toml_str(QUICK_TOML, "configs/quick.toml", overrides)
    }

    /// The built-in paper-method baseline ([`PAPER_METHOD_TOML`]) with `key=value` overrides.
    pub fn paper_method(overrides: &[String]) -> Result<Self> {
        Self::from_toml_str(PAPER_METHOD_TOML, "configs/baselines/paper-method.toml", overrides)
    }

    /// Reads a TOML file and applies `key=value` overrides. A file may start from another one
    /// with a top-level `base = "other.toml"` (relative to the file; chains allowed): its keys
    /// are laid over the base's, section by section.
    pub fn load(path: Option<&Path>, overrides: &[String]) -> Result<Self> {
        match path {
            Some(p) => {
                let table = load_table(p, 0)?;
                Self::from_table(table, &p.display().to_string(), overrides)
            }
            None => Self::from_toml_str("", "<defaults>", overrides),
        }
    }

    /// Parses TOML text (`name` for messages) and applies `key=value` overrides (`base` is not
    /// followed: there is no file to resolve it against).
    pub fn from_toml_str(text: &str, name: &str, overrides: &[String]) -> Result<Self> {
        let table: toml::Table =
            text.parse().map_err(|e| CoreError::Format { path: name.into(), problem: format!("invalid TOML: {e}") })?;
        Self::from_table(table, name, overrides)
    }

    fn from_table(mut table: toml::Table, name: &str, overrides: &[String]) -> Result<Self> {
        let name = name.to_string();
        for o in overrides {
            let (key, value) = o
                .split_once('=')
                .ok_or_else(|| CoreError::invalid(format!("override `{o}` is not of the form section.key=value")))?;
            let parts: Vec<&str> = key.trim().split('.').collect();
            let mut t = &mut table;
            for p in &parts[..parts.len() - 1] {
                t = t
                    .entry(p.to_string())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                    .as_table_mut()
                    .ok_or_else(|| CoreError::invalid(format!("override `{o}`: `{p}` is not a section")))?;
            }
            t.insert(parts[parts.len() - 1].to_string(), parse_value(value.trim()));
        }
        let cfg: Config = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| CoreError::Format { path: name.into(), problem: format!("{e}") })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Range checks; the error names the key.
    pub fn validate(&self) -> Result<()> {
        check(self.run.iterations >= 1, "run.iterations", "must be ≥ 1")?;
        check(self.run.image_binning >= 1, "run.image_binning", "must be ≥ 1")?;
        check(self.init.n1 + self.init.n2 >= 1, "init.n1", "n1 + n2 must be ≥ 1")?;
        check((0.0..1.0).contains(&self.init.mask_threshold), "init.mask_threshold", "must be in [0, 1)")?;
        check(
            (0.0..1.0).contains(&self.output.level_mask_threshold),
            "output.level_mask_threshold",
            "must be in [0, 1)",
        )?;
        check(
            (0.0..1.0).contains(&self.output.level_mask_threshold_two_views),
            "output.level_mask_threshold_two_views",
            "must be in [0, 1)",
        )?;
        check(self.init.knn >= 1, "init.knn", "must be ≥ 1")?;
        check((0.0..=100.0).contains(&self.init.seed_spacing_mm), "init.seed_spacing_mm", "must be in [0, 100] mm")?;
        check(
            self.init.seed_spacing_mm_two_views.is_none_or(|s| (0.0..=100.0).contains(&s)),
            "init.seed_spacing_mm_two_views",
            "must be in [0, 100] mm",
        )?;
        check(self.init.n2_voxel_mm >= 0.0, "init.n2_voxel_mm", "must be ≥ 0")?;
        check(
            self.model.scale_min_voxels > 0.0 && self.model.scale_max_voxels > self.model.scale_min_voxels,
            "model.scale_max_voxels",
            "need 0 < scale_min_voxels < scale_max_voxels",
        )?;
        check(self.model.k_sigma > 0.0 && self.model.k_sigma <= 20.0, "model.k_sigma", "must be in (0, 20]")?;
        check(self.model.initial_density >= 0.0, "model.initial_density", "must be ≥ 0")?;
        self.field.encoding.validate().map_err(|e| CoreError::invalid(format!("config `field.encoding`: {e}")))?;
        check((1..=4).contains(&self.field.hidden_layers), "field.hidden_layers", "must be in 1..=4")?;
        check((1..=MAX_HIDDEN).contains(&self.field.hidden), "field.hidden", "must be in 1..=4096")?;
        for (k, n) in [
            ("init.n1", self.init.n1),
            ("init.n2", self.init.n2),
            ("init.n2_two_views", self.init.n2_two_views.unwrap_or(0)),
            ("init.track_max_points", self.init.track_max_points),
            ("densify.max_gaussians", self.densify.max_gaussians),
            ("densify.reseed_n", self.densify.reseed_n),
            ("loss.pa_samples", self.loss.pa_samples),
        ] {
            check(n <= MAX_GAUSSIANS, k, "must be at most 20,000,000")?;
        }
        check(self.run.iterations <= 10_000_000, "run.iterations", "must be at most 10,000,000")?;
        check(self.run.member_iterations <= 10_000_000, "run.member_iterations", "must be at most 10,000,000")?;
        let seeds = &self.run.member_seeds;
        check(seeds.len() <= MAX_MEMBER_SEEDS, "run.member_seeds", "must list at most 8 seeds")?;
        check(
            seeds.iter().enumerate().all(|(i, s)| *s != self.run.seed && !seeds[..i].contains(s)),
            "run.member_seeds",
            "must differ from run.seed and from each other",
        )?;
        check(
            self.output.voxel_mm.is_finite() && self.output.voxel_mm >= 0.0,
            "output.voxel_mm",
            "must be ≥ 0 (0 = the case's voxel)",
        )?;
        check(self.init.n2_voxel_mm.is_finite(), "init.n2_voxel_mm", "must be finite")?;
        check(
            self.init.track_level.is_finite() && self.init.track_level > 0.0,
            "init.track_level",
            "must be finite and > 0 (× the vessel level)",
        )?;
        check((0.0..=10.0).contains(&self.init.track_start_mm), "init.track_start_mm", "must be in [0, 10] mm")?;
        check((1..=8).contains(&self.init.track_rounds), "init.track_rounds", "must be in 1..=8")?;
        for (k, px) in [
            ("init.prior_dilation_px", self.init.prior_dilation_px),
            ("init.residual_dilation_px", self.init.residual_dilation_px),
            ("init.track_prior_dilation_px", self.init.track_prior_dilation_px.unwrap_or(0)),
        ] {
            check(px <= MAX_DILATION_PX, k, "must be at most 64 pixels")?;
        }
        for (k, v) in [
            ("init.track_turn_cost", self.init.track_turn_cost),
            ("init.track_brightness_cost", self.init.track_brightness_cost),
            ("init.track_claimed_run_mm", self.init.track_claimed_run_mm),
        ] {
            check(v.is_finite() && v >= 0.0, k, "must be finite and ≥ 0")?;
        }
        check(
            (0.0..=100.0).contains(&self.init.connected_to_prior_mm),
            "init.connected_to_prior_mm",
            "must be in [0, 100] mm",
        )?;
        for (k, r) in [
            ("optim.lr_means", self.optim.lr_means),
            ("optim.lr_scales", self.optim.lr_scales),
            ("optim.lr_rotations", self.optim.lr_rotations),
            ("optim.lr_field", self.optim.lr_field),
            ("pose.lr_rotation_rad", self.pose.lr_rotation_rad),
            ("pose.lr_translation_mm", self.pose.lr_translation_mm),
        ] {
            check(r.iter().all(|v| v.is_finite() && *v >= 0.0), k, "learning rates must be finite and ≥ 0")?;
        }
        // Checked as the f32 the optimiser and the model use: 1e-50 passes as an f64 but is 0 in
        // f32 (NaN densities), and 1e40 is infinite.
        let f32_positive = |v: f64| (v as f32).is_finite() && (v as f32) >= f32::MIN_POSITIVE;
        check(
            f32_positive(self.optim.epsilon) && self.optim.epsilon <= 1.0,
            "optim.epsilon",
            "must be in [1.2e-38, 1] (a positive normal f32)",
        )?;
        check(
            self.optim.field_weight_decay.is_finite() && (0.0..=1e3).contains(&self.optim.field_weight_decay),
            "optim.field_weight_decay",
            "must be in [0, 1000]",
        )?;
        check(
            self.model.scale_min_voxels >= 1e-4 && self.model.scale_max_voxels <= 1e4,
            "model.scale_max_voxels",
            "scales must lie in [1e-4, 1e4] voxels",
        )?;
        check(
            self.model.initial_density.is_finite() && (self.model.initial_density as f32).is_finite(),
            "model.initial_density",
            "must be finite in f32",
        )?;
        check(
            self.densify.min_density.is_finite() && (0.0..=1e6).contains(&self.densify.min_density),
            "densify.min_density",
            "must be in [0, 1e6]",
        )?;
        check(
            self.densify.clone_scale_voxels.iter().all(|v| v.is_finite() && *v > 0.0 && *v <= 1e4),
            "densify.clone_scale_voxels",
            "both must be in (0, 1e4] voxels",
        )?;
        check(
            self.densify.grad_threshold.is_finite() && f32_positive(self.densify.grad_threshold),
            "densify.grad_threshold",
            "must be a positive finite f32",
        )?;
        check((0.0..1.0).contains(&self.loss.fn_tau), "loss.fn_tau", "must be in [0, 1)")?;
        check((0.0..=1.0).contains(&self.loss.fn_margin), "loss.fn_margin", "must be in [0, 1]")?;
        for (k, w) in [("loss.fn_weight", self.loss.fn_weight), ("loss.pa_weight", self.loss.pa_weight)] {
            check(w.is_finite() && (0.0..=1e6).contains(&w), k, "must be in [0, 1e6]")?;
        }
        check(self.loss.pa_k <= 256, "loss.pa_k", "must be at most 256 neighbours")?;
        check(
            self.loss.pa_radius_mm.is_finite() && self.loss.pa_radius_mm <= 100.0,
            "loss.pa_radius_mm",
            "must be at most 100 mm",
        )?;
        check(
            self.output.voxel_mm == 0.0 || (0.01..=100.0).contains(&self.output.voxel_mm),
            "output.voxel_mm",
            "must be 0 (the case's voxel) or in [0.01, 100] mm",
        )?;
        check(
            self.output.centreline_voxel_mm == 0.0 || (0.01..=100.0).contains(&self.output.centreline_voxel_mm),
            "output.centreline_voxel_mm",
            "must be 0 (the density volume's voxel) or in [0.01, 100] mm",
        )?;
        check(
            (0.0..1.0).contains(&self.output.centreline_bridge_fraction),
            "output.centreline_bridge_fraction",
            "must be in [0, 1)",
        )?;
        check(
            self.output.centreline_bridge_fraction_two_views.is_none_or(|f| (0.0..1.0).contains(&f)),
            "output.centreline_bridge_fraction_two_views",
            "must be in [0, 1)",
        )?;
        check(
            (0.0..=10.0).contains(&self.output.centreline_bridge_mm),
            "output.centreline_bridge_mm",
            "must be in [0, 10] mm",
        )?;
        check(
            (0.0..=10.0).contains(&self.output.centreline_bridge_prior_clearance_mm),
            "output.centreline_bridge_prior_clearance_mm",
            "must be in [0, 10] mm",
        )?;
        check(self.output.mc_level.is_finite(), "output.mc_level", "must be finite")?;
        check((0.0..=1.0).contains(&self.loss.lambda_dssim), "loss.lambda_dssim", "must be in [0, 1]")?;
        check(self.loss.fn_weight >= 0.0, "loss.fn_weight", "must be ≥ 0")?;
        check(self.loss.pa_weight >= 0.0, "loss.pa_weight", "must be ≥ 0")?;
        check(self.loss.pa_k >= 1, "loss.pa_k", "must be ≥ 1")?;
        check(self.loss.pa_radius_mm > 0.0, "loss.pa_radius_mm", "must be > 0")?;
        check(self.densify.every >= 1, "densify.every", "must be ≥ 1")?;
        check(
            (0.0..1.0).contains(&self.densify.reseed_mask_threshold),
            "densify.reseed_mask_threshold",
            "must be in [0, 1)",
        )?;
        check(self.densify.grad_threshold > 0.0, "densify.grad_threshold", "must be > 0")?;
        check(self.output.min_island_mm2 >= 0.0, "output.min_island_mm2", "must be ≥ 0")?;
        check((0.0..=1.0).contains(&self.output.min_confidence), "output.min_confidence", "must be in [0, 1]")?;
        check(
            (0.0..=1.0).contains(&self.output.connected_level_fraction),
            "output.connected_level_fraction",
            "must be in [0, 1]",
        )?;
        check(self.output.mc_level > 0.0, "output.mc_level", "must be > 0")?;
        check(
            (0.0..1.0).contains(&self.output.faint_mask_threshold),
            "output.faint_mask_threshold",
            "must be in [0, 1)",
        )?;
        check(
            self.output.faint_fraction > 0.0 && self.output.faint_fraction <= 1.0,
            "output.faint_fraction",
            "must be in (0, 1]",
        )?;
        check((0.0..=10.0).contains(&self.output.faint_radius_mm), "output.faint_radius_mm", "must be in [0, 10] mm")?;
        check(
            (0.0..1.0).contains(&self.output.near_prior_mask_threshold),
            "output.near_prior_mask_threshold",
            "must be in [0, 1)",
        )?;
        check((0.0..=100.0).contains(&self.output.near_prior_mm), "output.near_prior_mm", "must be in [0, 100] mm")?;
        check(
            self.output.keep_prior_mm >= 0.0 && self.output.keep_prior_mm <= 100.0,
            "output.keep_prior_mm",
            "must be in [0, 100] mm",
        )?;
        check((0.0..=10.0).contains(&self.output.centreline_scale), "output.centreline_scale", "must be in [0, 10]")?;
        for (v, k) in [
            (self.output.centreline_const_mm, "output.centreline_const_mm"),
            (self.output.centreline_const_mm_two_views.unwrap_or(0.0), "output.centreline_const_mm_two_views"),
            (self.output.centreline_min_branch_mm, "output.centreline_min_branch_mm"),
        ] {
            check((0.0..=100.0).contains(&v), k, "must be in [0, 100] mm")?;
        }
        check(
            (1..=MAX_SAMPLES).contains(&self.output.metric_samples),
            "output.metric_samples",
            "must be in 1..=10,000,000",
        )?;
        check(
            ["obj", "ply", "stl"].contains(&self.output.mesh_format.as_str()),
            "output.mesh_format",
            "must be obj, ply or stl",
        )?;
        Ok(())
    }

    /// The configuration as TOML (written next to every run).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }

    /// The configurations of the further image-seeded members (`run.member_seeds`): this one
    /// with each listed `run.seed`, and neither members nor a prior-only member of its own.
    pub fn seed_members(&self) -> Vec<Config> {
        self.run
            .member_seeds
            .iter()
            .map(|&seed| {
                let mut member = self.clone();
                member.run.seed = seed;
                member.run.member_seeds.clear();
                member.run.prior_only_member = false;
                member
            })
            .collect()
    }

    /// The configuration of the prior-only member (`run.prior_only_member`): this one without
    /// image seeds (with `run.member_tracks_max_views`, the tracked seeds its only ones) and
    /// without re-seeding. `None` when the member is off, the run has no image seeds (the member would
    /// be the run itself) or no Gaussians on the prior (the member would have none).
    pub fn prior_only_member(&self) -> Option<Config> {
        let seeded =
            (self.init.n2 > 0 || self.init.n2_two_views.is_some_and(|n| n > 0)) && self.init.n2_mode != SeedMode::None;
        if !self.run.prior_only_member || !seeded || self.init.n1 == 0 {
            return None;
        }
        let mut member = self.clone();
        member.init.n2 = 0;
        if self.run.member_tracks_max_views > 0 {
            member.init.n2_two_views = None;
            member.init.track_max_views = self.run.member_tracks_max_views;
        } else {
            member.init.n2_mode = SeedMode::None;
        }
        member.densify.reseed_at.clear();
        member.run.prior_only_member = false;
        member.run.member_seeds.clear();
        member.run.member_tracks_max_views = 0;
        member.run.stop_after = (self.run.member_iterations > 0).then_some(self.run.member_iterations);
        member.run.member_iterations = 0;
        Some(member)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_and_bad_values_name_the_key() {
        let err = Config::load(None, &["run.iterationz=5".into()]).unwrap_err().to_string();
        assert!(err.contains("iterationz"), "{err}");
        let err = Config::load(None, &["loss.lambda_dssim=2".into()]).unwrap_err().to_string();
        assert!(err.contains("loss.lambda_dssim"), "{err}");
        let err = Config::load(None, &["init.n2_mode=\"sideways\"".into()]).unwrap_err().to_string();
        assert!(err.contains("sideways") || err.contains("n2_mode"), "{err}");
        let ok = Config::load(None, &["run.iterations=7".into(), "init.n2_mode=uniform".into()]).unwrap();
        assert_eq!(ok.run.iterations, 7);
        assert_eq!(ok.init.n2_mode, SeedMode::Uniform);
        // Round trip through TOML.
        let text = ok.to_toml();
        let back: Config = toml::from_str(&text).unwrap();
        assert_eq!(back, ok);
    }

    #[test]
    fn two_view_runs_match_the_level_to_their_own_mask_threshold() {
        let mut out = OutputConfig::default();
        assert_eq!(out.level_mask_threshold_for(3, 0.05), 0.05, "the seeds' threshold by default");
        assert_eq!(out.level_mask_threshold_for(2, 0.05), out.level_mask_threshold_two_views);
        out.level_mask_threshold = 0.03;
        assert_eq!(out.level_mask_threshold_for(3, 0.05), 0.03);
        out.level_mask_threshold_two_views = 0.0;
        assert_eq!(out.level_mask_threshold_for(2, 0.05), 0.03, "0 falls back to the general threshold");
    }

    #[test]
    fn two_view_runs_trace_the_centreline_with_their_own_settings() {
        let cfg = Config::load(
            None,
            &[
                "output.centreline_const_mm=1.0".into(),
                "output.centreline_bridge_fraction=0.7".into(),
                "output.centreline_const_mm_two_views=2.0".into(),
                "output.centreline_bridge_fraction_two_views=0.5".into(),
            ],
        )
        .unwrap();
        let out = &cfg.output;
        assert_eq!((out.centreline_const_mm_for(3), out.centreline_bridge_fraction_for(3)), (1.0, 0.7));
        assert_eq!((out.centreline_const_mm_for(2), out.centreline_bridge_fraction_for(2)), (2.0, 0.5));
        let plain = OutputConfig { centreline_const_mm: 1.5, ..OutputConfig::default() };
        assert_eq!(plain.centreline_const_mm_for(2), 1.5, "absent: the general setting");
        for bad in ["output.centreline_bridge_fraction_two_views=1.0", "output.centreline_const_mm_two_views=-1"] {
            let err = Config::load(None, &[bad.into()]).unwrap_err().to_string();
            assert!(err.contains(bad.split('=').next().unwrap()), "{err}");
        }
    }

    #[test]
    fn two_view_runs_take_their_own_seed_count_and_spacing() {
        let mut init = InitConfig { n2: 10_000, seed_spacing_mm: 0.7, ..InitConfig::default() };
        assert_eq!((init.n2_for(2), init.seed_spacing_mm_for(2)), (10_000, 0.7), "absent: the general values");
        init.n2_two_views = Some(3_000);
        init.seed_spacing_mm_two_views = Some(0.0);
        assert_eq!((init.n2_for(2), init.seed_spacing_mm_for(2)), (3_000, 0.0));
        assert_eq!((init.n2_for(1), init.seed_spacing_mm_for(1)), (3_000, 0.0));
        assert_eq!((init.n2_for(3), init.seed_spacing_mm_for(3)), (10_000, 0.7));
        let cfg =
            Config::load(None, &["init.n2_two_views=500".into(), "init.seed_spacing_mm_two_views=1.5".into()]).unwrap();
        assert_eq!((cfg.init.n2_two_views, cfg.init.seed_spacing_mm_two_views), (Some(500), Some(1.5)));
        let back: Config = toml::from_str(&cfg.to_toml()).unwrap();
        assert_eq!(back, cfg, "round trip through TOML");
        let err = Config::load(None, &["init.seed_spacing_mm_two_views=-1".into()]).unwrap_err().to_string();
        assert!(err.contains("init.seed_spacing_mm_two_views"), "{err}");
    }

    #[test]
    fn the_prior_only_member_is_the_run_without_image_seeds() {
        let off = Config::load(None, &[]).unwrap();
        assert!(off.prior_only_member().is_none(), "off by default");
        let on = Config::load(None, &["run.prior_only_member=true".into()]).unwrap();
        let member = on.prior_only_member().expect("a member");
        assert_eq!((member.init.n2, member.init.n2_mode), (0, SeedMode::None));
        assert!(!member.run.prior_only_member, "a member has no member");
        let mut same = member.clone();
        same.init = on.init.clone();
        same.run.prior_only_member = true;
        assert_eq!(same, on, "only the seeds differ");
        let tracked =
            Config::load(None, &["run.prior_only_member=true".into(), "run.member_tracks_max_views=2".into()])
                .unwrap()
                .prior_only_member()
                .expect("a member");
        assert_eq!((tracked.init.n2_for(2), tracked.init.n2_for(3), tracked.init.n2_mode), (0, 0, on.init.n2_mode));
        assert_eq!(tracked.init.track_max_views, 2, "its seeds are the tracks of runs of up to 2 views");
        assert!(tracked.densify.reseed_at.is_empty() && tracked.run.member_tracks_max_views == 0);
        assert_eq!((tracked.run.stop_after, tracked.run.steps_to_train()), (None, tracked.run.iterations));
        let short = Config::load(
            None,
            &["run.prior_only_member=true".into(), "run.iterations=300".into(), "run.member_iterations=120".into()],
        )
        .unwrap();
        let short_member = short.prior_only_member().expect("a member");
        assert_eq!((short.run.steps_to_train(), short_member.run.steps_to_train()), (300, 120));
        assert_eq!(short_member.run.iterations, 300, "the member keeps the run's schedule");
        let mut long = short.clone();
        long.run.member_iterations = 500;
        assert_eq!(long.prior_only_member().unwrap().run.steps_to_train(), 300, "never past the run's end");
        let err = Config::load(None, &["run.member_iterations=20000000".into()]).unwrap_err().to_string();
        assert!(err.contains("run.member_iterations"), "{err}");
        let unseeded = Config::load(None, &["run.prior_only_member=true".into(), "init.n2=0".into()]).unwrap();
        assert!(unseeded.prior_only_member().is_none(), "without image seeds the member would be the run");
        let no_prior = Config::load(None, &["run.prior_only_member=true".into(), "init.n1=0".into()]).unwrap();
        assert!(no_prior.prior_only_member().is_none(), "without prior Gaussians the member would be empty");
    }

    #[test]
    fn seed_members_differ_from_the_run_only_in_their_seed() {
        assert!(Config::load(None, &[]).unwrap().seed_members().is_empty(), "none by default");
        let sets = ["run.member_seeds=[7, 8]".into(), "run.prior_only_member=true".into()];
        let on = Config::load(None, &sets).unwrap();
        let members = on.seed_members();
        assert_eq!(members.iter().map(|m| m.run.seed).collect::<Vec<_>>(), [7, 8]);
        for member in &members {
            assert!(member.seed_members().is_empty() && member.prior_only_member().is_none());
            let mut same = member.clone();
            same.run.seed = on.run.seed;
            same.run.member_seeds = on.run.member_seeds.clone();
            same.run.prior_only_member = true;
            assert_eq!(same, on, "only the seed differs");
        }
        assert!(on.prior_only_member().unwrap().seed_members().is_empty(), "the prior-only member has none");
        for bad in ["run.member_seeds=[42]", "run.member_seeds=[7, 7]", "run.member_seeds=[1,2,3,4,5,6,7,8,9]"] {
            let err = Config::load(None, &[bad.into()]).unwrap_err().to_string();
            assert!(err.contains("run.member_seeds"), "{bad}: {err}");
        }
    }

    #[test]
    fn a_config_can_start_from_a_base_file() {
        let dir = std::env::temp_dir().join(format!("ctadsa-cfg-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("base.toml"), "[run]\niterations = 77\nseed = 3\n[loss]\nfn_weight = 0.5\n").unwrap();
        std::fs::write(dir.join("sub/child.toml"), "base = \"../base.toml\"\n[run]\nseed = 9\n").unwrap();
        let c = Config::load(Some(&dir.join("sub/child.toml")), &["loss.pa_k=3".into()]).unwrap();
        assert_eq!((c.run.iterations, c.run.seed, c.loss.fn_weight, c.loss.pa_k), (77, 9, 0.5, 3));
        std::fs::write(dir.join("loop.toml"), "base = \"loop.toml\"\n").unwrap();
        let err = Config::load(Some(&dir.join("loop.toml")), &[]).unwrap_err().to_string();
        assert!(err.contains("loop.toml") && err.contains("base"), "{err}");
        std::fs::write(dir.join("typo.toml"), "base = \"base.toml\"\n[run]\niteratons = 5\n").unwrap();
        let err = Config::load(Some(&dir.join("typo.toml")), &[]).unwrap_err().to_string();
        assert!(err.contains("iteratons"), "{err}");
    }
}
