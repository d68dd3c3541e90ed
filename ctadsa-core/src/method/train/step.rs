//! One optimisation step: the step's views, the render, the losses, the Adam steps (model,
//! field, poses), and the loss logs read back every few steps.

use std::time::Instant;

use burn::lr_scheduler::constant::ConstantLr;
use burn::lr_scheduler::module_lr_scheduler::{ModuleLearningRate, ModuleLrScheduler};
use burn::module::ParamGroup;
use burn::optim::GradientsParams;
use burn::tensor::{Int, Tensor, TensorData};
use ctadsa_render::{ViewSet, render_with_stats};
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{CoreError, Result};
use crate::method::loss::LossTargets;
use crate::method::model::GaussianModel;
use ctadsa_ops::anchor_op::anchor_loss;
use ctadsa_ops::loss_op::total_loss;
use ctadsa_ops::readback::host_vec;

use super::{StageTimes, StepLog, Trainer, decayed};

impl Trainer {
    /// Learning rates of the Gaussians' groups and of the field.
    fn learning_rates(&self) -> (ModuleLearningRate, ModuleLearningRate) {
        let (t, total) = (self.iteration, self.cfg.run.iterations);
        let o = &self.cfg.optim;
        let field = ModuleLrScheduler::new(ConstantLr::new(decayed(o.lr_field, t, total))).step();
        let gaussians = ModuleLrScheduler::new(ConstantLr::new(decayed(o.lr_means, t, total)))
            .with_group(ParamGroup::from_path("means"), ConstantLr::new(decayed(o.lr_means, t, total)))
            .with_group(ParamGroup::from_path("raw_scales"), ConstantLr::new(decayed(o.lr_scales, t, total)))
            .with_group(ParamGroup::from_path("rotations"), ConstantLr::new(decayed(o.lr_rotations, t, total)))
            .step();
        (gaussians, field)
    }

    fn step_views(&self) -> Vec<usize> {
        let v = self.views.len();
        let k = self.cfg.run.views_per_step;
        if k == 0 || k >= v {
            return (0..v).collect();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.run.seed ^ (self.iteration as u64).wrapping_mul(0x2545_F491));
        let mut all: Vec<usize> = (0..v).collect();
        all.shuffle(&mut rng);
        all.truncate(k);
        all.sort_unstable();
        all
    }

    fn densify_active(&self) -> bool {
        let d = &self.cfg.densify;
        d.enabled && self.iteration < d.until
    }

    /// The views of this step and their targets (all views, or `run.views_per_step` of them).
    fn step_batch(&mut self) -> Result<(Vec<usize>, ViewSet, LossTargets)> {
        let idx = self.step_views();
        if idx.len() == self.views.len() {
            return Ok((idx, self.views.clone(), self.targets.clone()));
        }
        let it = Tensor::<1, Int>::from_data(
            TensorData::new(idx.iter().map(|&i| i as i64).collect::<Vec<_>>(), [idx.len()]),
            &self.device,
        );
        let (views, targets) = (self.views.select(&idx)?, self.targets.select(it));
        Ok((idx, views, targets))
    }

    /// Renders `gaussians` into `views` (the step's views, indices `idx` into the case's), each
    /// through its pose correction when poses are refined. `probe` collects the screen-space
    /// gradients that drive densification.
    fn render_views(
        &self,
        gaussians: &ctadsa_render::Gaussians,
        probe: Tensor<2>,
        idx: &[usize],
        views: &ViewSet,
    ) -> Result<Tensor<3>> {
        let Some((poses, _)) = &self.poses else {
            return Ok(render_with_stats(gaussians, probe, views, &self.settings)?);
        };
        let mut per_view = Vec::with_capacity(idx.len());
        for (k, &v) in idx.iter().enumerate() {
            let seen = poses.apply(gaussians, v);
            per_view.push(render_with_stats(&seen, probe.clone(), &views.select(&[k])?, &self.settings)?);
        }
        Ok(Tensor::cat(per_view, 0))
    }

    /// The prior-anchor term at iteration `t` (mean squared distance of a random sample of
    /// centres to the mean of their `loss.pa_k` nearest prior points, for those whose nearest is
    /// within `loss.pa_radius_mm`; 0 when none is), or `None` before `loss.pa_start`. Found on
    /// the device (one op on wgpu): nothing is read back.
    fn anchor_loss(&self, model: &GaussianModel, t: usize) -> Option<Tensor<1>> {
        let cfg = &self.cfg;
        let anchor = self.anchor.as_ref().filter(|_| t >= cfg.loss.pa_start && cfg.loss.pa_weight > 0.0)?;
        let n = model.len();
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.run.seed ^ 0x9A ^ (t as u64).wrapping_mul(0x9E37_79B9));
        let m = if cfg.loss.pa_samples == 0 { n } else { cfg.loss.pa_samples.min(n) };
        let sample: Vec<i64> =
            if m == n { (0..n as i64).collect() } else { (0..m).map(|_| rng.random_range(0..n as i64)).collect() };
        ctadsa_ops::readback::count_upload(m);
        let sel = Tensor::<1, Int>::from_data(TensorData::new(sample, [m]), &self.device);
        Some(anchor_loss(model.means.val(), sel, anchor))
    }

    /// The pose corrections' optimizer step at iteration `t` (from `pose.start` on).
    fn step_poses(&mut self, grads: &mut burn::tensor::Gradients, t: usize) {
        let Some((poses, mut optim)) = self.poses.take() else { return };
        let pose_grads = GradientsParams::from_module(grads, &poses);
        let poses = if t >= self.cfg.pose.start {
            let (p, iterations) = (&self.cfg.pose, self.cfg.run.iterations);
            let lr = ModuleLrScheduler::new(ConstantLr::new(decayed(p.lr_rotation_rad, t, iterations)))
                .with_group(
                    ParamGroup::from_path("translations_mm"),
                    ConstantLr::new(decayed(p.lr_translation_mm, t, iterations)),
                )
                .step();
            optim.step(lr, poses, pose_grads)
        } else {
            poses
        };
        self.poses = Some((poses, optim));
    }

    /// One optimisation step; its stage times. Its loss values reach `history` when the logs
    /// are next read (every `Trainer::log_every` steps, at a checkpoint, or
    /// [`Trainer::flush_logs`]); a loss that is not finite is reported then.
    pub fn step(&mut self) -> Result<StageTimes> {
        let cfg = self.cfg.clone();
        let t = self.iteration;
        let (lr, field_lr) = self.learning_rates();
        let (idx, views, targets) = self.step_batch()?;
        // Borrowed until the optimizer step, so that no error path can lose the model.
        let model = self.model.as_ref().expect("model present between steps");
        let mut times = StageTimes::default();
        let clock = Instant::now();
        let densities = model.field.forward(model.means.val());
        self.last_densities = self.densify_active().then(|| densities.clone().detach());
        let gaussians = ctadsa_render::Gaussians {
            means: model.means.val(),
            scales: model.scales(),
            rotations: model.rotations.val(),
            densities,
        };
        times.field = clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        // Its values are never read (the renderer writes the statistics into its gradient).
        let probe = Tensor::<2>::empty([model.len(), 2], &self.device).require_grad();
        let image = self.render_views(&gaussians, probe.clone(), &idx, &views)?;
        times.render = clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let (l1, ssim) = targets.image_terms(image.clone());
        let mut terms = Vec::new();
        let mut fn_value = None;
        if t >= cfg.loss.fn_start && cfg.loss.fn_weight > 0.0 {
            let f = targets.fn_loss(image, cfg.loss.fn_margin);
            fn_value = Some(f.clone().detach());
            terms.push((f, cfg.loss.fn_weight));
        }
        let mut pa_value = None;
        if let Some(pa) = self.anchor_loss(model, t) {
            pa_value = Some(pa.clone().detach());
            terms.push((pa, cfg.loss.pa_weight));
        }
        let loss = total_loss(l1.clone(), ssim.clone(), cfg.loss.lambda_dssim, terms);
        let values = [Some(loss.clone().detach()), Some(l1.detach()), Some(ssim.detach()), fn_value, pa_value];
        times.losses = clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let mut grads = loss.backward();
        self.step_poses(&mut grads, t);
        let model = self.model.as_ref().expect("model present between steps");
        if self.densify_active()
            && let Some(g) = probe.grad(&grads)
        {
            let sum = match self.device_stats.take() {
                Some(s) => s,
                None => self.stats.to_tensor(&self.device),
            };
            self.device_stats = Some(sum + g);
        }
        let field_grads = GradientsParams::from_module(&mut grads, &model.field);
        let gaussian_ids = [model.means.id, model.raw_scales.id, model.rotations.id];
        let grads = GradientsParams::from_params(&mut grads, model, &gaussian_ids);
        times.backward = clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let mut model = self.model.take().expect("model present between steps");
        model = self.optim.step(lr, model, grads);
        model.field = self.field_optim.step(field_lr, model.field, field_grads);
        times.optimizer = clock.elapsed().as_secs_f64();
        self.model = Some(model);
        self.iteration += 1;
        let d = &cfg.densify;
        if d.enabled && self.iteration > d.from && self.iteration <= d.until && self.iteration.is_multiple_of(d.every) {
            let clock = Instant::now();
            self.densify()?;
            times.densify = clock.elapsed().as_secs_f64();
        }
        if d.enabled && d.reseed_at.contains(&self.iteration) {
            let clock = Instant::now();
            self.reseed()?;
            times.densify += clock.elapsed().as_secs_f64();
        }
        let log = StepLog { iteration: self.iteration, gaussians: self.model().len(), times, ..StepLog::default() };
        self.pending_logs.push((log, values));
        if self.pending_logs.len() >= self.log_every.max(1) {
            // The read blocks until the device has done the queued steps: this step's `wait`.
            let clock = Instant::now();
            self.flush_logs()?;
            times.wait = clock.elapsed().as_secs_f64();
            if let Some(last) = self.history.last_mut() {
                last.times.wait = times.wait;
            }
        }
        Ok(times)
    }

    /// Reads the loss values of the steps not yet read (one read for all of them) into
    /// `history`. An error names the first step whose loss is not finite.
    pub fn flush_logs(&mut self) -> Result<()> {
        if self.pending_logs.is_empty() {
            return Ok(());
        }
        let pending = std::mem::take(&mut self.pending_logs);
        let present: Vec<Tensor<1>> = pending.iter().flat_map(|(_, v)| v.iter().flatten().cloned()).collect();
        let mut read = host_vec(Tensor::cat(present, 0)).into_iter();
        for (log, values) in pending {
            let [loss, l1, ssim, fn_loss, pa_loss] =
                values.map(|v| v.map_or(0.0, |_| f64::from(read.next().unwrap_or(f32::NAN))));
            if !loss.is_finite() {
                return Err(CoreError::invalid(format!("loss became {loss} at iteration {}", log.iteration - 1)));
            }
            self.history.push(StepLog { loss, l1, ssim, fn_loss, pa_loss, ..log });
        }
        Ok(())
    }

    /// The steps logged since the last call, oldest first (steps are logged every
    /// `Trainer::log_every` steps and by [`Trainer::flush_logs`]).
    pub fn new_logs(&mut self) -> Vec<StepLog> {
        let start = self.announced.min(self.history.len());
        self.announced = self.history.len();
        self.history[start..].to_vec()
    }

    /// Waits until the device has done all the work queued so far (a one-value read of the
    /// centres, which the last optimiser step wrote).
    pub fn sync(&self) {
        let means = self.model().means.val();
        if means.dims()[0] > 0 {
            let _ = means.slice([0..1, 0..1]).into_data();
        }
    }
}
