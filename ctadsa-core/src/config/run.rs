//! `[run]`: iterations, seeds, views, members, checkpoints.

use serde::{Deserialize, Serialize};

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
    /// The arrival maps' frames read through a median ([`crate::data::case::images::median_arrival`]):
    /// each filled pixel takes the median frame of the filled pixels within this many pixels
    /// (of the case's images, before `image_binning`). A real run's detected frames are off by a
    /// frame here and there; 0: the maps as they are, unless `arrival_noisy_share` finds a map
    /// noisy.
    pub arrival_median_px: u32,
    /// With `arrival_median_px` 0, a map whose [`arrival_noise`](crate::data::case::images::arrival_noise)
    /// (the share of its filled pixels whose frame differs from their 3 × 3 neighbours' median)
    /// exceeds this is read through the 1-pixel median. The BraVa cases' ideal maps score
    /// 0.011–0.025, with a frame error of 0.3 frames' standard deviation 0.11–0.12 and as a real
    /// run's (0.5) 0.30–0.32; the median made whole runs worse on the first two and better on the
    /// third (docs/RESULTS.md, "Arrival maps as a real run's"). 1: never.
    pub arrival_noisy_share: f64,
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
    /// from the prior as well (`init.track_*`, `method::tracking`; its only image
    /// seeds): a track follows a vessel out of the tree and rarely a ghost, so the member finds
    /// more of the missing vessels while, in the mean, the image-seeded models' ghosts still
    /// fall to half their density. 0 = the member has no image seeds.
    pub member_tracks_max_views: usize,
    /// The prior-only member re-seeds from the residual during training as the image-seeded
    /// models do (`densify.reseed_at`), where the case's arrival maps check the re-seeds
    /// (`init.arrival_reseeds`, two views, a case with maps): unchecked, re-seeds from two views
    /// would bring the member the ghosts it is there to outvote. Off: the member never re-seeds.
    pub member_reseeds: bool,
    /// The prior-only member stops after this many steps of the run's schedule (its learning
    /// rates, densification and loss terms keep the run's steps); 0 = `run.iterations`. Trained
    /// as long as a long run's image-seeded models, the member fits the views with its own seeds
    /// and lays down false surface (docs/RESULTS.md, "`configs/paper.toml`").
    pub member_iterations: usize,
    /// Where this configuration's training stops when it is a member's: set by
    /// [`RunConfig::prior_only_member`] from `run.member_iterations`; `None` = `run.iterations`.
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
            arrival_median_px: 0,
            arrival_noisy_share: 0.2,
            views: vec![],
            working_box: WorkingBoxSource::Inputs,
            prior_only_member: false,
            member_seeds: vec![],
            member_tracks_max_views: 0,
            member_reseeds: false,
            member_iterations: 0,
            stop_after: None,
        }
    }
}
