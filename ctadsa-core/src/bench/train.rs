//! The training step timed by stage on a case, with what it asks of the device: kernel launches,
//! blocking reads and uploads per step, and (on a GPU with timestamp queries) device time per
//! kernel.

use std::time::Instant;

use burn::tensor::Device;

use crate::config::Config;
use crate::data::case::Case;
use crate::error::Result;
use crate::method::densify::DensifyPlan;
use crate::method::train::{StageTimes, Trainer};
use ctadsa_ops::readback::Transfers;

/// What [`bench_train`] measures.
#[derive(Debug, Clone, Copy)]
pub struct TrainBenchSettings {
    /// Timed steps (after 2 warm-up steps); stage times are their mean.
    pub steps: usize,
    /// Further steps with every kernel timed on the device (0: none). Timing each launch slows
    /// the pass, so these steps are not part of the stage times.
    pub device_timed_steps: usize,
}

/// The figures of one [`bench_train`].
#[derive(Debug, Clone)]
pub struct TrainBenchReport {
    /// Gaussians after the warm-up.
    pub gaussians: usize,
    /// Views rendered per step.
    pub views_per_step: usize,
    /// Mean seconds per stage over the timed steps (`densify` is 0: timed separately).
    pub stages: StageTimes,
    /// Mean wall-clock seconds per step.
    pub per_step_s: f64,
    /// One densification call (s) and what it did.
    pub densify_s: f64,
    pub densify_plan: DensifyPlan,
    /// Initialisation (s), once.
    pub init_s: f64,
    /// Device reads and uploads over the timed steps.
    pub transfers: Transfers,
    /// Kernel launches over the timed steps (CubeCL devices; `None` on the CPU backend).
    pub launches: Option<crate::bench::KernelLaunches>,
    /// Launches and device time over the device-timed steps.
    pub device_timed: Option<crate::bench::KernelLaunches>,
    /// Timed steps (for per-step figures of `transfers` and `launches`).
    pub steps: usize,
    /// Device-timed steps.
    pub device_timed_steps: usize,
}

/// Times `settings.steps` training steps of `cfg` on `case` with every loss term active from
/// the first (the prior-anchoring and false-negative terms run for all but the first
/// `pa_start` / `fn_start` iterations of a run).
pub fn bench_train(
    case: &Case,
    mut cfg: Config,
    device: Device,
    settings: TrainBenchSettings,
) -> Result<TrainBenchReport> {
    cfg.loss.pa_start = 0;
    cfg.loss.fn_start = 0;
    let t0 = Instant::now();
    let mut trainer = Trainer::new(case, cfg.clone(), device)?;
    let init_s = t0.elapsed().as_secs_f64();
    for _ in 0..2 {
        trainer.step()?;
    }
    trainer.flush_logs()?;
    let steps = settings.steps.max(1);
    let mut sum = StageTimes::default();
    #[cfg(feature = "wgpu")]
    let watch = crate::bench::LaunchWatch::start(false);
    let before = Transfers::now();
    let start = Instant::now();
    for _ in 0..steps {
        let t = trainer.step()?;
        sum.field += t.field;
        sum.render += t.render;
        sum.losses += t.losses;
        sum.backward += t.backward;
        sum.optimizer += t.optimizer;
        sum.wait += t.wait;
    }
    trainer.sync();
    let per_step_s = start.elapsed().as_secs_f64() / steps as f64;
    let transfers = Transfers::now().since(before);
    #[cfg(feature = "wgpu")]
    let launches = Some(watch.take()).filter(|l| l.total() > 0);
    #[cfg(feature = "wgpu")]
    drop(watch);
    #[cfg(not(feature = "wgpu"))]
    let launches = None;
    trainer.flush_logs()?;
    let n = steps as f64;
    let stages = StageTimes {
        field: sum.field / n,
        render: sum.render / n,
        losses: sum.losses / n,
        backward: sum.backward / n,
        optimizer: sum.optimizer / n,
        densify: 0.0,
        wait: sum.wait / n,
    };
    let device_timed = device_timed_pass(&mut trainer, settings.device_timed_steps, launches.is_some())?;
    let t_dens = Instant::now();
    let densify_plan = trainer.densify()?;
    let densify_s = t_dens.elapsed().as_secs_f64();
    let views_per_step = match cfg.run.views_per_step {
        0 => trainer.views().len(),
        k => k.min(trainer.views().len()),
    };
    Ok(TrainBenchReport {
        gaussians: trainer.model().len(),
        views_per_step,
        stages,
        per_step_s,
        densify_s,
        densify_plan,
        init_s,
        transfers,
        launches,
        device_timed,
        steps,
        device_timed_steps: settings.device_timed_steps,
    })
}

/// `steps` more steps with every launch timed on the device (CubeCL devices only).
#[allow(unused_variables)]
fn device_timed_pass(
    trainer: &mut Trainer,
    steps: usize,
    cube_device: bool,
) -> Result<Option<crate::bench::KernelLaunches>> {
    if steps == 0 || !cube_device {
        return Ok(None);
    }
    #[cfg(feature = "wgpu")]
    {
        let watch = crate::bench::LaunchWatch::start(true);
        for _ in 0..steps {
            trainer.step()?;
        }
        trainer.sync();
        let timed = watch.take();
        drop(watch);
        trainer.flush_logs()?;
        Ok(Some(timed))
    }
    #[cfg(not(feature = "wgpu"))]
    Ok(None)
}
