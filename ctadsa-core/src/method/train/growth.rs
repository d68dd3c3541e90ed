//! Growing and pruning the model during training: densification (clone, split, prune) and
//! re-seeding from the residual.

use burn::module::Module;

use crate::error::{CoreError, Result};
use crate::method::densify::{self, DensifyStats};
use ctadsa_ops::readback::host_vec;

use super::Trainer;

impl Trainer {
    /// The densification statistics, read back from the device if they are there.
    pub(super) fn sync_stats(&mut self) {
        if let Some(sum) = &self.device_stats {
            self.stats = DensifyStats::from_interleaved(&host_vec(sum.clone()));
        }
    }

    /// Densification now (clone, split, prune), keeping parameters and Adam moments consistent.
    pub fn densify(&mut self) -> Result<densify::DensifyPlan> {
        self.sync_stats();
        let last_densities = self.last_densities.take();
        let model = self.model();
        let params = model.to_init();
        // Pruning needs only `density < min_density`, which one Adam step does not decide: the
        // last step's densities serve when they match the model, else a fresh field forward.
        let densities: Vec<f32> = match last_densities {
            Some(d) if d.dims()[0] == model.len() => host_vec(d),
            _ => host_vec(model.valid().densities()),
        };
        let plan = densify::plan(
            &params,
            &densities,
            &self.stats,
            &self.cfg.densify,
            model.bounds,
            &self.working_box,
            self.voxel_mm,
            self.iteration,
            self.cfg.run.seed,
        );
        let plan = self.without_arrival_ghosts(plan, &params)?;
        if plan.keep.is_empty() && plan.added.is_empty() {
            // An empty model renders nothing and cannot grow back: say so instead of finishing
            // the run with an empty mesh.
            return Err(CoreError::invalid(format!(
                "iteration {}: densification would prune all {} Gaussians (every density below \
                 densify.min_density = {:e}): the field's output collapsed to zero (field.output = \
                 \"relu\" can die this way; \"softplus\" cannot); the model is left as it was",
                self.iteration,
                densities.len(),
                self.cfg.densify.min_density
            )));
        }
        // Clones share the tensors; on an error the current model and optimizer stay as they are.
        let (model, optim) = densify::apply(model.clone(), self.optim.clone(), &plan, &self.device)?;
        self.stats = DensifyStats::new(model.len());
        self.device_stats = None;
        self.model = Some(model);
        self.optim = optim;
        Ok(plan)
    }

    /// `plan` without the Gaussians, kept or added, that the arrival maps call ghosts
    /// (`densify.arrival_prune`; [`crate::method::arrival::ghosts_by_arrival`]); as it is
    /// without maps for both of two views.
    fn without_arrival_ghosts(
        &self,
        mut plan: densify::DensifyPlan,
        params: &crate::method::model::GaussianInit,
    ) -> Result<densify::DensifyPlan> {
        let init = &self.cfg.init;
        let maps = crate::method::init::arrival_pair(init, self.views.views(), self.arrival.as_deref());
        let Some(maps) = maps.filter(|_| self.cfg.densify.arrival_prune) else { return Ok(plan) };
        let grid = crate::data::volume::Grid::covering(&self.working_box, self.voxel_mm)?;
        let solid = self.prior.as_ref().map(|p| crate::data::masks::prior_solid(p, grid));
        let ghosts = |means: &mut dyn Iterator<Item = &[f32]>| {
            let centres: Vec<glam::DVec3> =
                means.map(|m| glam::DVec3::new(f64::from(m[0]), f64::from(m[1]), f64::from(m[2]))).collect();
            let (tolerance, exit) = (init.arrival_tolerance_frames as f32, init.arrival_prior_exit_px);
            crate::method::arrival::ghosts_by_arrival(
                self.views.views(),
                maps,
                solid.as_ref(),
                &centres,
                tolerance,
                exit,
            )
        };
        let kept = ghosts(&mut plan.keep.iter().map(|&i| &params.means[3 * i..3 * i + 3]));
        let before = plan.keep.len();
        plan.keep = plan.keep.iter().zip(&kept).filter(|(_, g)| !**g).map(|(&i, _)| i).collect();
        plan.pruned += before - plan.keep.len();
        let added = ghosts(&mut plan.added.means.chunks_exact(3));
        let rows = |data: &[f32], cols: usize| -> Vec<f32> {
            data.chunks_exact(cols).zip(&added).filter(|(_, g)| !**g).flat_map(|(r, _)| r.iter().copied()).collect()
        };
        let a = &plan.added;
        plan.added = crate::method::model::GaussianInit {
            means: rows(&a.means, 3),
            raw_scales: rows(&a.raw_scales, 3),
            rotations: rows(&a.rotations, 4),
        };
        Ok(plan)
    }

    /// Re-seeding now (`densify.reseed_at`, [`crate::method::reseed`]): Gaussians added where
    /// every view's residual is bright; returns how many. Their scales come from their `init.knn`
    /// nearest new neighbours (at most a voxel), their rotations are the identity and their Adam
    /// moments zero. None with `densify.reseed_arrival_only` unless the arrival maps check them.
    pub fn reseed(&mut self) -> Result<usize> {
        let cfg = &self.cfg;
        let room = cfg.densify.max_gaussians.saturating_sub(self.model().len());
        let n = cfg.densify.reseed_n.min(room);
        let checked =
            crate::method::reseed::reseed_arrival_maps(&cfg.init, self.views.views(), self.arrival.as_deref())
                .is_some();
        if n == 0 || (cfg.densify.reseed_arrival_only && !checked) {
            return Ok(0);
        }
        let renders = self.render_all()?;
        let grid = crate::data::volume::Grid::covering(&self.working_box, self.voxel_mm)?;
        let solid = self.prior.as_ref().map(|p| crate::data::masks::prior_solid(p, grid));
        let threshold = if cfg.densify.reseed_mask_threshold > 0.0 {
            cfg.densify.reseed_mask_threshold
        } else {
            cfg.init.mask_threshold
        };
        let drawn = cfg.densify.reseed_from_model.then(|| self.drawn_voxels(grid));
        let inputs = crate::method::reseed::ResidualInputs {
            views: self.views.views(),
            targets: &self.images,
            renders: &renders,
            prior: solid.as_ref(),
            bounds: &self.working_box,
            voxel_mm: self.voxel_mm,
            drawn: drawn.as_ref(),
            arrival: self.arrival.as_deref(),
        };
        let seed = cfg.run.seed ^ (self.iteration as u64).wrapping_mul(0x9E37_79B9);
        let centres =
            crate::method::reseed::residual_seeds(&cfg.init, &inputs, threshold, cfg.densify.reseed_occluded, n, seed)?;
        if centres.is_empty() {
            return Ok(0);
        }
        // At most a voxel: a new Gaussian must not blot out what the model already draws.
        let scales: Vec<f64> = crate::method::init::knn_scales(&centres, cfg.init.knn, self.voxel_mm)
            .into_iter()
            .map(|s| s.min(self.voxel_mm))
            .collect();
        let added = crate::method::init::isotropic_gaussians(&centres, &scales, self.model().bounds);
        let plan = densify::DensifyPlan { keep: (0..self.model().len()).collect(), added, ..Default::default() };
        let (model, optim) = densify::apply(self.model().clone(), self.optim.clone(), &plan, &self.device)?;
        self.stats = DensifyStats::new(model.len());
        self.device_stats = None;
        self.last_densities = None;
        self.model = Some(model);
        self.optim = optim;
        self.n2 += centres.len();
        Ok(centres.len())
    }

    /// The voxels of `grid` holding the centre of a Gaussian at least as dense as the median one.
    fn drawn_voxels(&self, grid: crate::data::volume::Grid) -> crate::data::volume::Volume<u8> {
        let model = self.model().valid();
        let densities = host_vec(model.densities());
        let means = host_vec(model.means.val());
        let median = crate::stats::percentile(&densities.iter().map(|&d| f64::from(d)).collect::<Vec<_>>(), 50.0);
        let mut drawn = crate::data::volume::Volume::<u8>::zeros(grid);
        for (c, &d) in means.chunks_exact(3).zip(&densities) {
            if f64::from(d) < median {
                continue;
            }
            let ijk = [0, 1, 2].map(|a| ((f64::from(c[a]) - grid.origin_mm[a]) / grid.spacing_mm[a]).floor());
            if ijk.iter().zip(grid.dims).all(|(&i, n)| i >= 0.0 && i < n as f64) {
                let idx = grid.index(ijk[0] as usize, ijk[1] as usize, ijk[2] as usize);
                drawn.data[idx] = 1;
            }
        }
        drawn
    }
}
