//! The optimisation loop: render the model into the DSA views, compute the losses, take an Adam
//! step with per-group exponentially decaying learning rates, densify, checkpoint and resume.

use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::lr_scheduler::constant::ConstantLr;
use burn::lr_scheduler::module_lr_scheduler::{ModuleLearningRate, ModuleLrScheduler};
use burn::module::{Module, Param, ParamGroup};
use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Int, Tensor, TensorData};
use ctadsa_render::{ConeBeamView, RenderSettings, ViewSet, render_with_stats};
use glam::DVec3;
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::config::{AdamImpl, Config, WorkingBoxSource};
use crate::data::case::Case;
use crate::data::case::images::{Image, bin_image};
use crate::data::mesh::TriMesh;
use crate::data::mesh::sample::sample_surface;
use crate::data::projector::correction::PoseCorrection;
use crate::data::volume::BoxMm;
use crate::error::{CoreError, Result, read_file, to_json, write_file};
use crate::method::densify::{self, DensifyStats};
use crate::method::field_health::DensitySpread;
use crate::method::init::initialise;
use crate::method::loss::LossTargets;
use crate::method::model::{GaussianInit, GaussianModel, ScaleBounds};
use crate::method::pose::ViewPoses;
use crate::method::working_box::working_box_from_inputs;
use ctadsa_ops::anchor_op::grid::AnchorGrid;
use ctadsa_ops::anchor_op::{DeviceGrid, anchor_targets};
use ctadsa_ops::optim::FusedAdam;
use ctadsa_ops::optim::state_edit::edit_state;
use ctadsa_ops::readback::host_vec;

/// Seconds spent per stage in one step.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    pub field: f64,
    pub render: f64,
    pub losses: f64,
    pub backward: f64,
    pub optimizer: f64,
    pub densify: f64,
}

impl StageTimes {
    /// The whole step (s).
    pub fn total(&self) -> f64 {
        self.field + self.render + self.losses + self.backward + self.optimizer + self.densify
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

/// What a checkpoint stores besides the model and optimizer.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct CheckpointState {
    iteration: usize,
    gaussians: usize,
    n1: usize,
    n2: usize,
    history: Vec<StepLog>,
    /// The working box of the run (absent in checkpoints of older versions).
    #[serde(default)]
    working_box: Option<BoxMm>,
    /// The settings that shape the trajectory ([`training_settings`]); a resume with other
    /// settings is refused (absent in checkpoints of older versions).
    #[serde(default)]
    training_settings: Option<String>,
    /// The case the run belongs to ([`case_fingerprint`]); a resume on another case is refused
    /// (absent in checkpoints of older versions).
    #[serde(default)]
    case: Option<String>,
}

/// The case's name and a hash of its `case.json` content (views, geometry, prior, volume).
fn case_fingerprint(case: &Case) -> String {
    let text = serde_json::to_string(&case.file).unwrap_or_default();
    // FNV-1a, 64 bits: stable across builds and platforms.
    let hash = text.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3));
    format!("{} {hash:016x}", case.file.name)
}

/// The configuration less what may change on resume (`[output]`, `run.iterations`,
/// `run.checkpoint_every`, `run.prior_only_member`), as TOML.
fn training_settings(cfg: &Config) -> String {
    let mut c = cfg.clone();
    c.output = Default::default();
    c.run.iterations = 0;
    c.run.checkpoint_every = 0;
    // The member is a second model beside this one; it changes nothing of this one's training.
    c.run.prior_only_member = false;
    c.to_toml()
}

/// `section.key` → value of every setting in a TOML document.
fn flat_settings(text: &str) -> std::collections::BTreeMap<String, String> {
    fn flatten(prefix: &str, v: &toml::Value, out: &mut std::collections::BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                    flatten(&key, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let mut out = std::collections::BTreeMap::new();
    if let Ok(v) = toml::from_str::<toml::Table>(text) {
        flatten("", &toml::Value::Table(v), &mut out);
    }
    out
}

/// The training settings (`section.key`) in which a checkpoint's `saved` settings and the
/// `current` ones differ. `[output]` never counts; a key that only one side has (a setting added
/// or removed between versions) counts only when its value is not the default.
fn settings_differences(saved: &str, current: &str) -> Vec<String> {
    let (a, b) = (flat_settings(saved), flat_settings(current));
    let defaults = flat_settings(&training_settings(&Config::default()));
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    keys.into_iter()
        .filter(|k| !k.starts_with("output."))
        .filter(|k| {
            let value = |side: &std::collections::BTreeMap<String, String>| side.get(*k).or(defaults.get(*k)).cloned();
            value(&a) != value(&b)
        })
        .cloned()
        .collect()
}

/// The case's images and views after the run's view selection and binning.
pub fn prepare_views(case: &Case, cfg: &Config) -> Result<(ViewSet, Vec<Image>)> {
    let case = if cfg.run.views.is_empty() { case.clone() } else { case.select_views(&cfg.run.views)? };
    let b = cfg.run.image_binning.max(1);
    let (w, h) = case.views.image_size();
    if b > w.min(h) {
        return Err(CoreError::invalid(format!(
            "config `run.image_binning` = {b} is larger than the {w} × {h} px detector of {}",
            case.dir.display()
        )));
    }
    let views: Vec<ConeBeamView> =
        case.views.views().iter().map(|v| v.binned(b)).collect::<std::result::Result<_, _>>()?;
    let images: Vec<Image> = case.images.iter().map(|img| bin_image(img, b)).collect();
    Ok((ViewSet::new(views)?, images))
}

/// Density that makes the initial renders carry the images' total intensity: the detector
/// integral of a blob is its mass over depth² (normalised image coordinates).
pub fn estimate_initial_density(views: &ViewSet, images: &[Image], init: &GaussianInit, bounds: ScaleBounds) -> f64 {
    let mut masses = Vec::new();
    for (v, img) in views.views().iter().zip(images) {
        let [fx, fy] = v.intrinsics().focal_px;
        let depth = v.source_mm().length();
        let sum: f64 = img.data.iter().map(|&x| x.max(0.0) as f64).sum();
        masses.push(sum / (fx * fy) * depth * depth);
    }
    let target_mass = masses.iter().sum::<f64>() / masses.len().max(1) as f64;
    let unit_mass: f64 = init
        .raw_scales
        .chunks_exact(3)
        .map(|r| {
            let s: f64 = r.iter().map(|&x| bounds.scale_mm_f64(x as f64)).product();
            (2.0 * std::f64::consts::PI).powf(1.5) * s
        })
        .sum();
    if unit_mass > 0.0 && target_mass > 0.0 { target_mass / unit_mass } else { 1.0 }
}

/// The run's working box (`run.working_box`).
pub fn run_working_box(
    case: &Case,
    cfg: &Config,
    views: &ViewSet,
    images: &[Image],
    prior: Option<&TriMesh>,
) -> Result<BoxMm> {
    match cfg.run.working_box {
        WorkingBoxSource::Case => Ok(case.file.volume.bounds()),
        WorkingBoxSource::Inputs => working_box_from_inputs(views.views(), images, prior, cfg.init.mask_threshold),
    }
}

/// Refuses before training an output grid (`output.voxel_mm` over the working box) that the
/// outputs could not be written on.
fn check_output_grid(cfg: &Config, working_box: &BoxMm, case_voxel_mm: f64) -> Result<()> {
    let voxel = if cfg.output.voxel_mm > 0.0 { cfg.output.voxel_mm } else { case_voxel_mm };
    crate::data::volume::Grid::covering(working_box, voxel)
        .map(|_| ())
        .map_err(|e| CoreError::invalid(format!("config key `output.voxel_mm` = {voxel} mm: {e}")))
}

/// A training run in memory.
pub struct Trainer {
    pub cfg: Config,
    pub device: Device,
    pub views: ViewSet,
    pub images: Vec<Image>,
    targets: LossTargets,
    /// The prior-surface points for the anchoring term, on the device.
    anchor: Option<DeviceGrid>,
    model: Option<GaussianModel>,
    /// Adam of the Gaussians' parameters (densification edits its state).
    optim: ModuleOptimizer,
    /// Adam of the opacity field (never edited: its 2 × 16.8 M moments at paper scale stay put).
    field_optim: ModuleOptimizer,
    pub stats: DensifyStats,
    /// The densification statistics accumulated on the device since `stats` was last read
    /// (`[N, 2]`: sum, visible count), started from `stats`; read back only when needed.
    device_stats: Option<Tensor<2>>,
    /// Steps whose loss values are still on the device (loss, L1, SSIM, FN, PA; `None`: a term
    /// not computed, 0), read back together every [`Trainer::log_every`] steps.
    pending_logs: Vec<(StepLog, [Option<Tensor<1>>; 5])>,
    /// Steps between reads of the loss values (each read waits for the device; 1 reads every
    /// step). The training itself does not depend on it.
    pub log_every: usize,
    /// Entries of `history` already handed out by [`Trainer::new_logs`].
    announced: usize,
    /// The densities of the last step's field forward (detached; one Adam step behind the
    /// parameters), kept while densification is active so that a densify call reuses them
    /// instead of a second field forward (at paper scale the larger part of its cost).
    last_densities: Option<Tensor<1>>,
    /// Iterations done.
    pub iteration: usize,
    pub history: Vec<StepLog>,
    pub working_box: BoxMm,
    pub voxel_mm: f64,
    pub n1: usize,
    pub n2: usize,
    pub settings: RenderSettings,
    /// Per-view pose corrections and their optimizer (`[pose] enabled`).
    poses: Option<(ViewPoses, ModuleOptimizer)>,
    /// The case's [`case_fingerprint`], saved with every checkpoint.
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

/// Loads a checkpoint's model into `skeleton`. A checkpoint of a version whose hash table padded
/// every level to `T` rows (`[F, levels · T]`) is loaded as such and compacted to `[F, R]`; the
/// table parameter's id is then returned, so that its Adam moments can be compacted too.
fn load_model(skeleton: GaussianModel, path: &Path) -> Result<(GaussianModel, Option<u64>)> {
    let error = |e: &dyn std::fmt::Debug| CoreError::format(path, format!("cannot load model (same config?): {e:?}"));
    let first = match skeleton.clone().try_load_file(path) {
        Ok(model) => return Ok((model, None)),
        Err(e) => e,
    };
    let c = skeleton.field.grid.config;
    let mut padded = skeleton;
    let table = &padded.field.grid.tables;
    let zeros = Tensor::<2>::zeros([c.features, c.padded_rows()], &table.val().device());
    padded.field.grid.tables = Param::initialized(table.id, zeros);
    let Ok(mut model) = padded.try_load_file(path) else { return Err(error(&first)) };
    let table = &model.field.grid.tables;
    let device = table.val().device();
    let compact = c.compact_table(&host_vec(table.val()));
    let compact = Tensor::<2>::from_data(TensorData::new(compact, [c.features, c.rows()]), &device);
    let id = table.id;
    model.field.grid.tables = Param::initialized(id, compact.require_grad());
    Ok((model, Some(id.val())))
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
        let init = initialise(
            &cfg.init,
            views.views(),
            &images,
            prior.as_ref(),
            &working_box,
            voxel_mm,
            bounds,
            cfg.run.seed,
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
        trainer.case_fingerprint = case_fingerprint(case);
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
        let settings = RenderSettings { k_sigma: cfg.model.k_sigma, ..Default::default() };
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
    /// the device: nothing is read back.
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
        let chosen = model.means.val().select(0, sel);
        let (target, keep) = anchor_targets(chosen.clone(), anchor);
        let squared = (chosen - target).powi_scalar(2).sum_dim(1).reshape([m]);
        let anchored = keep.clone().sum().clamp_min(1.0);
        Some((squared * keep).sum() / anchored)
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
    /// are next read (every [`Trainer::log_every`] steps, at a checkpoint, or
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
        let (render_loss, l1, ssim) = targets.render_loss(image.clone(), cfg.loss.lambda_dssim);
        let mut loss = render_loss;
        let mut fn_value = None;
        if t >= cfg.loss.fn_start && cfg.loss.fn_weight > 0.0 {
            let f = targets.fn_loss(image, cfg.loss.fn_margin);
            fn_value = Some(f.clone().detach());
            loss = loss + f.mul_scalar(cfg.loss.fn_weight);
        }
        let mut pa_value = None;
        if let Some(pa) = self.anchor_loss(model, t) {
            pa_value = Some(pa.clone().detach());
            loss = loss + pa.mul_scalar(cfg.loss.pa_weight);
        }
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
            self.flush_logs()?;
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
    /// [`Trainer::log_every`] steps and by [`Trainer::flush_logs`]).
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

    /// The densification statistics, read back from the device if they are there.
    fn sync_stats(&mut self) {
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

    /// Re-seeding now (`densify.reseed_at`, [`crate::method::reseed`]): Gaussians added where
    /// every view's residual is bright; returns how many. Their scales come from their `init.knn`
    /// nearest new neighbours (at most a voxel), their rotations are the identity and their Adam
    /// moments zero.
    pub fn reseed(&mut self) -> Result<usize> {
        let cfg = &self.cfg;
        let room = cfg.densify.max_gaussians.saturating_sub(self.model().len());
        let n = cfg.densify.reseed_n.min(room);
        if n == 0 {
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

    /// Writes a checkpoint folder (model, optimizer, state); returns its path.
    /// The folder is written under a temporary name and renamed when complete, so a kill while
    /// saving leaves the previous checkpoints as they were.
    pub fn save_checkpoint(&mut self, dir: &Path) -> Result<PathBuf> {
        self.flush_logs()?;
        self.sync_stats();
        let done = dir.join(format!("ckpt-{:07}", self.iteration));
        let ck = dir.join(format!(".ckpt-{:07}.partial-{}", self.iteration, std::process::id()));
        if ck.exists() {
            std::fs::remove_dir_all(&ck).map_err(|e| CoreError::io(&ck, e))?;
        }
        std::fs::create_dir_all(&ck).map_err(|e| CoreError::io(&ck, e))?;
        self.model()
            .clone()
            .save_file(ck.join("model.bpk"))
            .map_err(|e| CoreError::format(&ck.join("model.bpk"), format!("cannot save model: {e:?}")))?;
        for (optim, name) in [(&self.optim, "optim.bpk"), (&self.field_optim, "optim-field.bpk")] {
            optim
                .save(ck.join(name))
                .map_err(|e| CoreError::format(&ck.join(name), format!("cannot save optimizer: {e:?}")))?;
        }
        if let Some((poses, optim)) = &self.poses {
            let (mp, op) = (ck.join("poses.bpk"), ck.join("poses-optim.bpk"));
            poses.clone().save_file(&mp).map_err(|e| CoreError::format(&mp, format!("cannot save poses: {e:?}")))?;
            optim.save(&op).map_err(|e| CoreError::format(&op, format!("cannot save pose optimizer: {e:?}")))?;
        }
        let stats: Vec<u8> = self.stats.sum.iter().chain(&self.stats.count).flat_map(|v| v.to_le_bytes()).collect();
        write_file(&ck.join("stats.bin"), &stats)?;
        let state = CheckpointState {
            iteration: self.iteration,
            gaussians: self.model().len(),
            n1: self.n1,
            n2: self.n2,
            history: self.history.clone(),
            working_box: Some(self.working_box),
            training_settings: Some(training_settings(&self.cfg)),
            case: Some(self.case_fingerprint.clone()),
        };
        let state_path = ck.join("state.json");
        write_file(&state_path, to_json(&state, &state_path)?.as_bytes())?;
        // A checkpoint of this iteration already there (a re-export saves the last one again)
        // moves aside before the new one moves in, and is deleted only after: at every moment a
        // complete checkpoint is listed by `checkpoints` (the moved one as a fallback).
        let old = dir.join(format!(".ckpt-{:07}.old-{}", self.iteration, std::process::id()));
        if done.exists() {
            std::fs::rename(&done, &old).map_err(|e| CoreError::io(&done, e))?;
        }
        std::fs::rename(&ck, &done).map_err(|e| CoreError::io(&done, e))?;
        // Folders a killed process left half-written are never read, and replaced ones are done
        // with; remove them.
        for stale in std::fs::read_dir(dir).map_err(|e| CoreError::io(dir, e))?.flatten() {
            let name = stale.file_name();
            let Some(name) = name.to_str() else { continue };
            let replaced = name.starts_with(".ckpt-") && name.contains(".old-");
            if (name.starts_with(".ckpt-") && name.contains(".partial-")) || replaced {
                let _ = std::fs::remove_dir_all(stale.path());
            }
        }
        Ok(done)
    }

    /// Restores a run from a checkpoint folder written by [`Trainer::save_checkpoint`], with the
    /// same case and configuration.
    pub fn resume(case: &Case, cfg: Config, device: Device, checkpoint: &Path) -> Result<Self> {
        cfg.validate()?;
        let state_path = checkpoint.join("state.json");
        let state: CheckpointState = serde_json::from_slice(&read_file(&state_path)?)
            .map_err(|e| CoreError::format(&state_path, format!("invalid checkpoint state: {e}")))?;
        if let Some(saved) = &state.training_settings {
            let differ = settings_differences(saved, &training_settings(&cfg));
            if !differ.is_empty() {
                return Err(CoreError::format(
                    &state_path,
                    format!(
                        "this checkpoint belongs to a run with other settings ({}); resume with the run's \
                         config.toml, or start a new run",
                        differ.join(", ")
                    ),
                ));
            }
        }
        let fingerprint = case_fingerprint(case);
        if let Some(saved) = state.case.as_ref().filter(|saved| **saved != fingerprint) {
            return Err(CoreError::format(
                &state_path,
                format!(
                    "this checkpoint belongs to another case (`{saved}`, this one is `{fingerprint}`: name and a \
                     hash of case.json); resume with the run's case, or start a new run"
                ),
            ));
        }
        let (views, images) = prepare_views(case, &cfg)?;
        let prior = case.prior_mesh()?;
        let working_box = match state.working_box {
            Some(b) => b,
            None => run_working_box(case, &cfg, &views, &images, prior.as_ref())?,
        };
        let voxel_mm = case.file.volume.voxel_mm;
        let bounds = ScaleBounds::from_voxel(voxel_mm, cfg.model.scale_min_voxels, cfg.model.scale_max_voxels);
        let n = state.gaussians;
        let model_path = checkpoint.join("model.bpk");
        let model_bytes = std::fs::metadata(&model_path).map_err(|e| CoreError::io(&model_path, e))?.len();
        // Ten f32 per Gaussian (mean, raw scale, rotation) must be in the model file.
        if n == 0 || n > crate::config::MAX_GAUSSIANS || model_bytes < 40 * n as u64 {
            return Err(CoreError::format(
                &state_path,
                format!("`gaussians` = {n} does not fit the checkpoint's model.bpk ({model_bytes} bytes)"),
            ));
        }
        let skeleton_init =
            GaussianInit { means: vec![0.0; 3 * n], raw_scales: vec![0.0; 3 * n], rotations: vec![0.0; 4 * n] };
        let size = working_box.size_mm();
        let field = GaussianModel::new_field(
            &cfg.field,
            working_box.min_mm.map(|v| v as f32),
            size.map(|v| v as f32),
            1.0,
            cfg.run.seed ^ 0xF1E1D,
            &device,
        );
        let skeleton = GaussianModel::new(&skeleton_init, field, bounds, &device);
        let (model, padded_table) = load_model(skeleton, &model_path)?;
        let mut t = Self::assemble(
            cfg,
            device,
            views,
            images,
            prior.as_ref(),
            model,
            working_box,
            voxel_mm,
            state.n1,
            state.n2,
        )?;
        // Checkpoints of versions with one optimizer hold both states in optim.bpk.
        let optim_path = checkpoint.join("optim.bpk");
        let field_path = Some(checkpoint.join("optim-field.bpk")).filter(|p| p.exists()).unwrap_or(optim_path.clone());
        let (gaussian_optim, field_optim) = new_optimizers(&t.cfg);
        let load = |optim: ModuleOptimizer, path: &Path| {
            optim.load(path).map_err(|e| CoreError::format(path, format!("cannot load optimizer state: {e:?}")))
        };
        t.optim = load(gaussian_optim, &optim_path)?;
        t.field_optim = load(field_optim, &field_path)?;
        if let Some(id) = padded_table {
            let c = t.cfg.field.encoding;
            let padded = [c.features, c.padded_rows()];
            t.field_optim = edit_state(t.field_optim, |s| {
                (s.param_id == id && s.shape == padded)
                    .then(|| (c.compact_table(&s.values), vec![c.features, c.rows()]))
            })
            .map_err(|e| CoreError::format(&field_path, e.to_string()))?;
        }
        if let Some((poses, optim)) = t.poses.take() {
            let (mp, op) = (checkpoint.join("poses.bpk"), checkpoint.join("poses-optim.bpk"));
            let poses = poses
                .try_load_file(&mp)
                .map_err(|e| CoreError::format(&mp, format!("cannot load view poses (was [pose] enabled?): {e:?}")))?;
            let optim =
                optim.load(&op).map_err(|e| CoreError::format(&op, format!("cannot load pose optimizer: {e:?}")))?;
            t.poses = Some((poses, optim));
        }
        let stats = read_file(&checkpoint.join("stats.bin"))?;
        let vals: Vec<f32> = stats.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        if vals.len() == 2 * n {
            t.stats = DensifyStats { sum: vals[..n].to_vec(), count: vals[n..].to_vec() };
        }
        t.case_fingerprint = fingerprint;
        t.iteration = state.iteration;
        t.history = state.history;
        t.announced = t.history.len();
        Ok(t)
    }

    /// The complete checkpoint folders under `dir` (`ckpt-` + iteration), newest first.
    /// A checkpoint being replaced (`.ckpt-N.old-PID`, see [`Trainer::save_checkpoint`]) comes
    /// after the complete one of its iteration, so that a kill between the two renames still
    /// leaves one to resume from.
    pub fn checkpoints(dir: &Path) -> Vec<PathBuf> {
        let Ok(entries) = std::fs::read_dir(dir) else { return Vec::new() };
        let mut cks: Vec<(usize, bool, PathBuf)> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter_map(|p| {
                let name = p.file_name()?.to_str()?;
                let (n, current) = match name.strip_prefix("ckpt-") {
                    Some(n) => (n.parse().ok()?, true),
                    None => (name.strip_prefix(".ckpt-")?.split_once(".old-")?.0.parse().ok()?, false),
                };
                p.join("state.json").exists().then_some((n, current, p))
            })
            .collect();
        cks.sort();
        cks.into_iter().rev().map(|(_, _, p)| p).collect()
    }

    /// Percentiles of the field's densities at the Gaussians' centres (one field forward).
    pub fn density_spread(&self) -> Option<DensitySpread> {
        DensitySpread::of(&host_vec(self.model().valid().densities()))
    }

    /// Host copy of the Gaussians: `(means, scales, rotations, densities)` row-major.
    pub fn host_gaussians(&self) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
        let m = self.model().valid();
        let v2 = |t: Tensor<2>| host_vec(t);
        let d = host_vec(m.densities());
        (v2(m.means.val()), v2(m.scales()), v2(m.rotations.val()), d)
    }

    /// Final renders of all views `[V][H·W]`.
    pub fn render_all(&self) -> Result<Vec<Vec<f32>>> {
        let m = self.model().valid();
        let gaussians = m.gaussians();
        let img = match &self.poses {
            None => ctadsa_render::render(&gaussians, &self.views, &self.settings)?,
            Some((poses, _)) => {
                let poses = poses.valid();
                let mut per_view = Vec::with_capacity(self.views.len());
                for v in 0..self.views.len() {
                    let seen = poses.apply(&gaussians, v);
                    per_view.push(ctadsa_render::render(&seen, &self.views.select(&[v])?, &self.settings)?);
                }
                Tensor::cat(per_view, 0)
            }
        };
        let (w, h) = self.views.image_size();
        let flat: Vec<f32> = host_vec(img);
        Ok(flat.chunks((w * h) as usize).map(<[f32]>::to_vec).collect())
    }

    /// The learned pose corrections of the run's views (`None` when pose refinement is off).
    pub fn pose_corrections(&self) -> Option<Vec<PoseCorrection>> {
        self.poses.as_ref().map(|(p, _)| p.corrections())
    }

    /// Centre of mass of the Gaussians (mm), for quick diagnostics.
    pub fn centroid(&self) -> DVec3 {
        let (m, ..) = self.host_gaussians();
        let n = (m.len() / 3).max(1) as f64;
        m.chunks_exact(3).fold(DVec3::ZERO, |acc, c| acc + DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)) / n
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

    #[test]
    fn settings_differences_name_changed_keys_and_ignore_output_and_new_defaults() {
        let base = Config::default();
        let saved = training_settings(&base);
        assert!(settings_differences(&saved, &saved).is_empty());
        let mut other = base.clone();
        other.init.n1 += 1;
        other.loss.pa_weight *= 2.0;
        other.output.mc_level = 0.5;
        other.run.iterations += 10;
        other.run.prior_only_member = !base.run.prior_only_member;
        assert_eq!(settings_differences(&saved, &training_settings(&other)), vec!["init.n1", "loss.pa_weight"]);
        // A checkpoint of a version without a setting that now exists: equal while the setting
        // keeps its default, different once it does not.
        let without = saved.replace("knn = 3\n", "");
        assert_ne!(without, saved, "the test removes a key");
        assert!(settings_differences(&without, &saved).is_empty());
        let mut knn = base.clone();
        knn.init.knn = 5;
        assert_eq!(settings_differences(&without, &training_settings(&knn)), vec!["init.knn"]);
        // Old checkpoints stored [output]; it never counts.
        assert!(settings_differences(&(saved.clone() + "\n[output]\nmc_level = 0.9\n"), &saved).is_empty());
    }

    #[test]
    fn checkpoints_are_listed_newest_first_and_incomplete_ones_are_skipped() {
        let dir = std::env::temp_dir().join(format!("ctadsa-ckpts-{}", std::process::id()));
        for (name, complete) in [
            ("ckpt-0000100", true),
            ("ckpt-0000020", true),
            ("ckpt-0000300", false),
            (".ckpt-0000400.partial-9", true),
            (".ckpt-0000100.old-9", true),
            (".ckpt-0000500.old-9", true),
        ] {
            std::fs::create_dir_all(dir.join(name)).unwrap();
            if complete {
                std::fs::write(dir.join(name).join("state.json"), "{}").unwrap();
            }
        }
        let names: Vec<String> =
            Trainer::checkpoints(&dir).iter().map(|p| p.file_name().unwrap().to_string_lossy().into()).collect();
        // A replaced checkpoint (moved aside while its successor moves in) is a fallback after
        // the current one of its iteration.
        assert_eq!(names, [".ckpt-0000500.old-9", "ckpt-0000100", ".ckpt-0000100.old-9", "ckpt-0000020"]);
        assert!(Trainer::checkpoints(&dir.join("absent")).is_empty());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn initial_density_makes_the_blobs_carry_the_images_mass() {
        let view = ConeBeamView::from_tigre(&ctadsa_render::TigreGeometry::reference(0.0)).unwrap();
        let views = ViewSet::new(vec![view]).unwrap();
        let (w, h) = (view.width(), view.height());
        let bounds = ScaleBounds { min_mm: 0.1, max_mm: 4.0 };
        let raw = bounds.inverse(1.0);
        let init =
            GaussianInit { means: vec![0.0; 6], raw_scales: vec![raw; 6], rotations: [1.0, 0.0, 0.0, 0.0].repeat(2) };
        let image = |v: f32| Image { width: w, height: h, data: vec![v; (w * h) as usize] };
        let d1 = estimate_initial_density(&views, &[image(1.0)], &init, bounds);
        let d2 = estimate_initial_density(&views, &[image(2.0)], &init, bounds);
        assert!(d1 > 0.0 && (d2 / d1 - 2.0).abs() < 1e-9, "density scales with the image mass: {d1} {d2}");
        assert_eq!(estimate_initial_density(&views, &[image(0.0)], &init, bounds), 1.0, "empty images: 1");
    }
}
