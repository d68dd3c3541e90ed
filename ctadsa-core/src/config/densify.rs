//! `[densify]`: densification, pruning and re-seeding.

use serde::{Deserialize, Serialize};

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
    /// Re-seed only where the case's arrival maps check the re-seeds (`init.arrival_reseeds`,
    /// two views, a case with maps); set for the prior-only member by `run.member_reseeds`.
    #[serde(skip)]
    pub reseed_arrival_only: bool,
    /// Two views whose arrival maps check the seeds (`init.arrival_*`, a case with maps): at
    /// each densification, Gaussians farther than a voxel from the prior whose centre does not
    /// fill at once in both views ([`crate::method::arrival::ghosts_by_arrival`], the seeds'
    /// test) are pruned as ghosts, and their clones with them: their pixels are left to the
    /// re-seeds and the vessels. quick-512, 8 shared BraVa trees (2 views, arrival maps): CD_ROI
    /// 1.618 → 1.516 mm (8 of 8 trees), centreline 52.1 / 69.9 → 54.7 / 70.9 % (docs/RESULTS.md,
    /// "Two views: where the centreline loses").
    pub arrival_prune: bool,
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
            reseed_arrival_only: false,
            arrival_prune: false,
        }
    }
}
