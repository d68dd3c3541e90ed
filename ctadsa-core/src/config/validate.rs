//! Range checks of a configuration; every error names the key.

use super::*;
use crate::data::case::MAX_VIEWS;
use crate::error::{CoreError, Result};

fn check(ok: bool, key: &str, what: impl std::fmt::Display) -> Result<()> {
    if ok { Ok(()) } else { Err(CoreError::invalid(format!("config key `{key}`: {what}"))) }
}

impl Config {
    /// Range checks; the error names the key.
    pub fn validate(&self) -> Result<()> {
        check(self.run.iterations >= 1, "run.iterations", "must be ≥ 1")?;
        check(self.run.image_binning >= 1, "run.image_binning", "must be ≥ 1")?;
        check(self.run.arrival_median_px <= 5, "run.arrival_median_px", "must be in [0, 5]")?;
        check((0.0..=1.0).contains(&self.run.arrival_noisy_share), "run.arrival_noisy_share", "must be in [0, 1]")?;
        let views = &self.run.views;
        check(
            views.len() <= MAX_VIEWS,
            "run.views",
            format!("lists {} views; a case has at most {MAX_VIEWS}", views.len()),
        )?;
        check(
            (1..views.len()).all(|k| !views[..k].contains(&views[k])),
            "run.views",
            format!("{views:?} names a view twice (its pixels would pass for a second direction)"),
        )?;
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
        check(
            self.model.render_row_split == 0
                || (self.model.render_row_split.is_power_of_two() && self.model.render_row_split <= 64),
            "model.render_row_split",
            "must be 0 (by the detector's height) or a power of two ≤ 64",
        )?;
        check(self.model.initial_density >= 0.0, "model.initial_density", "must be ≥ 0")?;
        self.field.encoding.validate().map_err(|e| CoreError::invalid(format!("config `field.encoding`: {e}")))?;
        check((1..=4).contains(&self.field.hidden_layers), "field.hidden_layers", "must be in 1..=4")?;
        check((1..=MAX_HIDDEN).contains(&self.field.hidden), "field.hidden", "must be in 1..=4096")?;
        for (k, n) in [
            ("init.n1", self.init.n1),
            ("init.n2", self.init.n2),
            ("init.n2_two_views", self.init.n2_two_views.unwrap_or(0)),
            ("init.track_max_points", self.init.track_max_points),
            ("init.track_max_points_arrival", self.init.track_max_points_arrival.unwrap_or(0)),
            ("densify.max_gaussians", self.densify.max_gaussians),
            ("densify.reseed_n", self.densify.reseed_n),
            ("loss.pa_samples", self.loss.pa_samples),
        ] {
            check(n <= MAX_GAUSSIANS, k, "must be at most 20,000,000")?;
        }
        check(self.run.iterations <= 10_000_000, "run.iterations", "must be at most 10,000,000")?;
        // Looked up at every step.
        check(self.densify.reseed_at.len() <= 1000, "densify.reseed_at", "must list at most 1,000 iterations")?;
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
        check(
            self.init.track_rounds_arrival.is_none_or(|r| (1..=8).contains(&r)),
            "init.track_rounds_arrival",
            "must be in 1..=8",
        )?;
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
            (0.0..=1.0).contains(&self.output.arrival_min_agreement),
            "output.arrival_min_agreement",
            "must be in [0, 1]",
        )?;
        check(
            (0.0..=1000.0).contains(&self.init.arrival_tolerance_frames),
            "init.arrival_tolerance_frames",
            "must be in [0, 1000]",
        )?;
        check(self.init.arrival_prior_exit_px <= 64, "init.arrival_prior_exit_px", "must be at most 64 (pixels)")?;
        check(
            self.output.arrival_prior_exit_px.is_none_or(|r| r <= 64),
            "output.arrival_prior_exit_px",
            "must be at most 64 (pixels)",
        )?;
        check(
            (0.0..=1000.0).contains(&self.output.arrival_tolerance_frames),
            "output.arrival_tolerance_frames",
            "must be in [0, 1000]",
        )?;
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
            (self.output.centreline_ridge_weight, "output.centreline_ridge_weight"),
            (self.output.centreline_ridge_weight_two_views.unwrap_or(0.0), "output.centreline_ridge_weight_two_views"),
            (self.output.centreline_ridge_weight_arrival.unwrap_or(0.0), "output.centreline_ridge_weight_arrival"),
        ] {
            check((0.0..=1.0).contains(&v), k, "must be in [0, 1]")?;
        }
        for (v, k) in [
            (self.output.centreline_const_mm, "output.centreline_const_mm"),
            (self.output.centreline_const_mm_two_views.unwrap_or(0.0), "output.centreline_const_mm_two_views"),
            (self.output.centreline_const_mm_arrival.unwrap_or(0.0), "output.centreline_const_mm_arrival"),
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
}
