//! The optimisation loop: render the model into the DSA views, compute the losses, take an Adam
//! step with per-group exponentially decaying learning rates, densify, checkpoint and resume.
//!
//! [`Trainer`] holds a run in memory; its responsibilities live one per file: [`setup`] (views,
//! images and working box of a run), `step` (one optimisation step and its logs), `growth`
//! (densification and re-seeding), `checkpoint` (save, list, resume) and `readout` (what the
//! outputs read of the model).

mod checkpoint;
mod growth;
mod readout;
pub mod setup;
mod step;

use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::{Device, Tensor};
use ctadsa_render::{RenderSettings, ViewSet};
use serde::{Deserialize, Serialize};

use crate::config::{AdamImpl, Config};
use crate::data::case::Case;
use crate::data::case::images::Image;
use crate::data::mesh::TriMesh;
use crate::data::mesh::sample::sample_surface;
use crate::data::volume::BoxMm;
use crate::error::Result;
use crate::method::arrival::seed_arrival_maps;
use crate::method::densify::DensifyStats;
use crate::method::init::initialise;
use crate::method::loss::LossTargets;
use crate::method::model::{GaussianModel, ScaleBounds};
use crate::method::pose::ViewPoses;
use ctadsa_ops::anchor_op::DeviceGrid;
use ctadsa_ops::anchor_op::grid::AnchorGrid;
use ctadsa_ops::optim::FusedAdam;

use setup::check_output_grid;
pub use setup::{estimate_initial_density, prepare_views, run_working_box};

/// Seconds spent per stage in one step.
///
/// On a GPU backend the stages from `field` to `optimizer` only queue device work and return;
/// the device's time shows in `wait`, the step that reads the queued steps' losses back
/// (every `Trainer::log_every` steps) blocking until the device has done them. On the CPU
/// backends the stages do the work and `wait` is near 0. Their sum ([`StageTimes::total`]) is
/// the step's wall time either way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    pub field: f64,
    pub render: f64,
    pub losses: f64,
    pub backward: f64,
    pub optimizer: f64,
    pub densify: f64,
    /// Blocked reading the losses back (absent in step logs written before it existed: 0).
    #[serde(default)]
    pub wait: f64,
}

impl StageTimes {
    /// The whole step (s).
    pub fn total(&self) -> f64 {
        self.field + self.render + self.losses + self.backward + self.optimizer + self.densify + self.wait
    }
}

/// One step's numbers.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StepLog {
    /// Iterations done after this step.
    pub iteration: usize,
    pub loss: f64,
    pub l1: f64,
    pub ssim: f64,
    pub fn_loss: f64,
    pub pa_loss: f64,
    pub gaussians: usize,
    pub times: StageTimes,
}

/// A training run in memory.
pub struct Trainer {
    cfg: Config,
    device: Device,
    views: ViewSet,
    images: Vec<Image>,
    targets: LossTargets,
    /// The prior-surface points for the anchoring term, on the device.
    anchor: Option<DeviceGrid>,
    model: Option<GaussianModel>,
    /// Adam of the Gaussians' parameters (densification edits its state).
    optim: ModuleOptimizer,
    /// Adam of the opacity field (never edited: its 2 × 16.8 M moments at paper scale stay put).
    field_optim: ModuleOptimizer,
    stats: DensifyStats,
    /// The densification statistics accumulated on the device since `stats` was last read
    /// (`[N, 2]`: sum, visible count), started from `stats`; read back only when needed.
    device_stats: Option<Tensor<2>>,
    /// Steps whose loss values are still on the device (loss, L1, SSIM, FN, PA; `None`: a term
    /// not computed, 0), read back together every `Trainer::log_every` steps.
    pending_logs: Vec<(StepLog, [Option<Tensor<1>>; 5])>,
    /// Steps between reads of the loss values (each read waits for the device; 1 reads every
    /// step). The training itself does not depend on it.
    log_every: usize,
    /// Entries of `history` already handed out by [`Trainer::new_logs`].
    announced: usize,
    /// The densities of the last step's field forward (detached; one Adam step behind the
    /// parameters), kept while densification is active so that a densify call reuses them
    /// instead of a second field forward (at paper scale the larger part of its cost).
    last_densities: Option<Tensor<1>>,
    /// The views' arrival maps, read when the configuration checks seeds against them
    /// (`init.arrival_*`, [`crate::config::InitConfig::checks_arrival`]); the re-seeds use them.
    arrival: Option<Vec<Image>>,
    /// Iterations done.
    iteration: usize,
    history: Vec<StepLog>,
    working_box: BoxMm,
    voxel_mm: f64,
    n1: usize,
    n2: usize,
    settings: RenderSettings,
    /// Per-view pose corrections and their optimizer (`[pose] enabled`).
    poses: Option<(ViewPoses, ModuleOptimizer)>,
    /// The case's [`Case::fingerprint`], saved with every checkpoint.
    case_fingerprint: String,
    /// The prior mesh, for re-seeding (`densify.reseed_at`); its voxels are made when needed.
    prior: Option<TriMesh>,
}

/// Steps between reads of the loss values by default.
pub const DEFAULT_LOG_EVERY: usize = 10;

/// The Adam of the Gaussians and the Adam of the field (coupled L2 weight decay on the field).
fn new_optimizers(cfg: &Config) -> (ModuleOptimizer, ModuleOptimizer) {
    let eps = cfg.optim.epsilon as f32;
    let decay = (cfg.optim.field_weight_decay > 0.0).then_some(cfg.optim.field_weight_decay as f32);
    match cfg.optim.adam {
        AdamImpl::Fused => (
            ModuleOptimizer::from(FusedAdam::new(eps)),
            ModuleOptimizer::from(FusedAdam::new(eps).with_weight_decay(decay)),
        ),
        AdamImpl::Burn => (
            AdamConfig::new().with_epsilon(eps).init(),
            AdamConfig::new().with_epsilon(eps).with_weight_decay(decay.map(WeightDecayConfig::new)).init(),
        ),
    }
}

/// `init · (final / init)^(t / T)` (linear when one end is 0).
pub fn decayed(range: [f64; 2], t: usize, total: usize) -> f64 {
    let f = (t as f64 / total.max(1) as f64).clamp(0.0, 1.0);
    let [a, b] = range;
    if a > 0.0 && b > 0.0 { a * (b / a).powf(f) } else { a + (b - a) * f }
}

impl Trainer {
    /// Initialises a run from a case.
    pub fn new(case: &Case, cfg: Config, device: Device) -> Result<Self> {
        cfg.validate()?;
        let (views, images) = prepare_views(case, &cfg)?;
        let prior = case.prior_mesh()?;
        let working_box = run_working_box(case, &cfg, &views, &images, prior.as_ref())?;
        let voxel_mm = case.file.volume.voxel_mm;
        check_output_grid(&cfg, &working_box, voxel_mm)?;
        let bounds = ScaleBounds::from_voxel(voxel_mm, cfg.model.scale_min_voxels, cfg.model.scale_max_voxels);
        let arrival = if cfg.init.checks_arrival() { seed_arrival_maps(case, &cfg)? } else { None };
        let init = initialise(
            &cfg.init,
            views.views(),
            &images,
            prior.as_ref(),
            &working_box,
            voxel_mm,
            bounds,
            cfg.run.seed,
            arrival.as_deref(),
        )?;
        let rho0 = if cfg.model.initial_density > 0.0 {
            cfg.model.initial_density
        } else {
            estimate_initial_density(&views, &images, &init.gaussians, bounds)
        };
        let size = working_box.size_mm();
        let field = GaussianModel::new_field(
            &cfg.field,
            working_box.min_mm.map(|v| v as f32),
            size.map(|v| v as f32),
            rho0 as f32,
            cfg.run.seed ^ 0xF1E1D,
            &device,
        );
        let model = GaussianModel::new(&init.gaussians, field, bounds, &device);
        let mut trainer =
            Self::assemble(cfg, device, views, images, prior.as_ref(), model, working_box, voxel_mm, init.n1, init.n2)?;
        trainer.case_fingerprint = case.fingerprint();
        trainer.arrival = arrival;
        Ok(trainer)
    }

    #[allow(clippy::too_many_arguments)]
    fn assemble(
        cfg: Config,
        device: Device,
        views: ViewSet,
        images: Vec<Image>,
        prior: Option<&TriMesh>,
        model: GaussianModel,
        working_box: BoxMm,
        voxel_mm: f64,
        n1: usize,
        n2: usize,
    ) -> Result<Self> {
        let targets = LossTargets::new(&images, cfg.loss.fn_tau, &device);
        let anchor = prior.and_then(|p| {
            let n = ((p.area_mm2() / (0.05 * 0.05)) as usize).clamp(20_000, 400_000);
            let points: Vec<[f64; 3]> =
                sample_surface(p, n, cfg.run.seed ^ 0xA11C).iter().map(|v| v.to_array()).collect();
            (!points.is_empty()).then(|| {
                let grid = AnchorGrid::new(&points, cfg.loss.pa_radius_mm);
                DeviceGrid::new(&grid, cfg.loss.pa_k, cfg.loss.pa_radius_mm, &device)
            })
        });
        let n = model.len();
        let settings =
            RenderSettings { k_sigma: cfg.model.k_sigma, row_split: cfg.model.render_row_split, ..Default::default() };
        let poses = cfg.pose.enabled.then(|| {
            let fixed: &[usize] = if cfg.pose.fix_first_view { &[0] } else { &[] };
            (ViewPoses::new(views.len(), fixed, &device), AdamConfig::new().with_epsilon(1e-12).init())
        });
        let (gaussian_optim, field_optim) = new_optimizers(&cfg);
        let cfg_reseed_off = cfg.densify.reseed_at.is_empty();
        Ok(Self {
            poses,
            optim: gaussian_optim,
            field_optim,
            cfg,
            device,
            views,
            images,
            targets,
            anchor,
            model: Some(model),
            stats: DensifyStats::new(n),
            device_stats: None,
            pending_logs: Vec::new(),
            log_every: DEFAULT_LOG_EVERY,
            announced: 0,
            last_densities: None,
            arrival: None,
            iteration: 0,
            history: Vec::new(),
            working_box,
            voxel_mm,
            n1,
            n2,
            settings,
            case_fingerprint: String::new(),
            prior: prior.filter(|_| !cfg_reseed_off).cloned(),
        })
    }

    /// The current model.
    pub fn model(&self) -> &GaussianModel {
        self.model.as_ref().expect("model present between steps")
    }

    /// The run's configuration.
    pub fn cfg(&self) -> &Config {
        &self.cfg
    }

    /// The run's configuration, to change between steps (a densification threshold, a
    /// schedule). Checkpoints record the changed settings, so a resume needs them too.
    pub fn cfg_mut(&mut self) -> &mut Config {
        &mut self.cfg
    }

    /// The run's views (after `run.views` and `run.image_binning`).
    pub fn views(&self) -> &ViewSet {
        &self.views
    }

    /// The DSA images of [`Trainer::views`], in the same order.
    pub fn images(&self) -> &[Image] {
        &self.images
    }

    /// Iterations done.
    pub fn iteration(&self) -> usize {
        self.iteration
    }

    /// The steps whose losses have been read back, oldest first.
    pub fn history(&self) -> &[StepLog] {
        &self.history
    }

    /// The run's working box (mm, world).
    pub fn working_box(&self) -> &BoxMm {
        &self.working_box
    }

    /// The case's voxel size (mm).
    pub fn voxel_mm(&self) -> f64 {
        self.voxel_mm
    }

    /// Gaussians seeded on the prior (N1) and from the images (N2, re-seeding included).
    pub fn seed_counts(&self) -> (usize, usize) {
        (self.n1, self.n2)
    }

    /// The render settings of the run.
    pub fn settings(&self) -> &RenderSettings {
        &self.settings
    }

    /// Steps between reads of the loss values (1 reads every step; the training itself does not
    /// depend on it).
    pub fn set_log_every(&mut self, steps: usize) {
        self.log_every = steps.max(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decayed_is_log_linear_between_its_ends_and_linear_through_zero() {
        assert_eq!(decayed([1e-2, 1e-4], 0, 100), 1e-2);
        assert!((decayed([1e-2, 1e-4], 50, 100) - 1e-3).abs() < 1e-15, "geometric midpoint");
        assert!((decayed([1e-2, 1e-4], 100, 100) - 1e-4).abs() < 1e-18);
        assert_eq!(decayed([1e-2, 1e-4], 500, 100), decayed([1e-2, 1e-4], 100, 100), "clamped after the end");
        assert_eq!(decayed([0.0, 1.0], 25, 100), 0.25, "linear when one end is 0");
    }
}
