//! The configurations of a run's ensemble members.

use super::{Config, SeedMode};

impl Config {
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
    /// without re-seeding (with `run.member_reseeds`, re-seeding only where the arrival maps
    /// check it). `None` when the member is off, the run has no image seeds (the member would be
    /// the run itself) or no Gaussians on the prior (the member would have none).
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
        if self.run.member_reseeds {
            member.densify.reseed_arrival_only = true;
        } else {
            member.densify.reseed_at.clear();
        }
        member.run.member_reseeds = false;
        member.run.prior_only_member = false;
        member.run.member_seeds.clear();
        member.run.member_tracks_max_views = 0;
        member.run.stop_after = (self.run.member_iterations > 0).then_some(self.run.member_iterations);
        member.run.member_iterations = 0;
        Some(member)
    }
}
