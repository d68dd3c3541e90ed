//! One completion run in its output folder: start afresh, overwrite or resume (falling back to
//! older checkpoints), train with periodic checkpoints, stop with a checkpoint when asked, then
//! write the outputs and the report. The CLI and the tests drive runs through [`run_completion`];
//! what they show of a run (a progress bar, log lines) comes through a [`Monitor`].

use std::path::{Path, PathBuf};

use burn::tensor::Device;

use crate::config::Config;
use crate::data::case::{CASE_FILE, Case};
use crate::error::{CoreError, Result, remove_path};
use crate::method::train::{StepLog, Trainer};
use crate::output::export::{RunModels, RunSummary, write_outputs};
use crate::output::report::write_report;
use crate::run::lock::FolderLock;

/// How a run starts in its output folder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start<'a> {
    /// A new run; refused when the folder holds one.
    Fresh,
    /// A new run; an earlier run's checkpoints and summary in the folder are removed first.
    Overwrite,
    /// From `"latest"` (the newest usable checkpoint in the folder) or a checkpoint folder.
    Resume(&'a str),
}

/// How a run ended.
#[derive(Debug, Clone)]
pub enum Outcome {
    /// All iterations done; outputs written.
    Finished(Box<RunSummary>),
    /// Stopped on request ([`Monitor::should_stop`]) after saving this checkpoint.
    Interrupted { checkpoint: PathBuf },
}

/// What a caller sees of a run. Every method has a default that does nothing.
pub trait Monitor {
    /// A line worth telling the user (which checkpoint is resumed, which one is unusable).
    fn note(&mut self, _line: &str) {}
    /// Training is about to start (or continue) at `trainer.iteration()`.
    fn started(&mut self, _trainer: &Trainer, _cfg: &Config) {}
    /// One step is done; `logged`: the steps whose loss values were read back since the last
    /// call, oldest first (every `Trainer::log_every` steps, and at checkpoints).
    fn stepped(&mut self, _trainer: &Trainer, _logged: &[StepLog]) {}
    /// Checked after every step: `true` saves a checkpoint and ends the run.
    fn should_stop(&self) -> bool {
        false
    }
}

/// A monitor that shows nothing and never stops a run.
pub struct Silent;

impl Monitor for Silent {}

/// The folder, inside a run's folder, of the prior-only member's checkpoints
/// (`run.prior_only_member`).
pub const MEMBER_DIR: &str = "prior-only-member";

/// The folder, inside a run's folder, of the image-seeded member trained with `seed`
/// (`run.member_seeds`).
pub fn seed_member_dir(seed: u64) -> String {
    format!("{SEED_MEMBER_PREFIX}{seed}")
}

/// The start of the folder names of [`seed_member_dir`].
const SEED_MEMBER_PREFIX: &str = "seed-member-";

/// Whether `out` holds (part of) a run: a summary or a checkpoint (its own or its member's).
pub fn holds_run(out: &Path) -> bool {
    out.join("summary.json").exists() || holds_checkpoints(out)
}

/// Whether `out` holds a checkpoint of a trained model (its own or its prior-only member's).
pub fn holds_checkpoints(out: &Path) -> bool {
    !Trainer::checkpoints(&out.join("checkpoints")).is_empty()
        || !Trainer::checkpoints(&out.join(MEMBER_DIR).join("checkpoints")).is_empty()
}

/// The lock file of a run folder in use ([`FolderLock`]).
pub const RUN_LOCK: &str = "run.lock";

/// The files and folders that a run writes into its folder, besides `mesh*.{obj,ply,stl}` and
/// the members' folders ([`run_outputs_in`] lists them all).
const RUN_OUTPUTS: [&str; 17] = [
    "summary.json",
    "report.html",
    "config.toml",
    "density.nii.gz",
    "gaussians.ply",
    "renders",
    "loss.png",
    "loss.csv",
    "mesh.png",
    "mesh-completion.png",
    "centreline.swc",
    "centreline.vtp",
    "centreline.png",
    "branches.csv",
    "confidence.png",
    "poses.json",
    "checkpoints",
];

/// The run outputs (files or folders a run writes) that the folder `out` holds, by name: what
/// `--overwrite` removes, and what a fresh run refuses to write over.
pub(super) fn run_outputs_in(out: &Path) -> Vec<String> {
    let meshes = ["obj", "ply", "stl"]
        .into_iter()
        .flat_map(|f| ["mesh", "mesh-raw", "mesh-extracted"].map(|stem| format!("{stem}.{f}")));
    let mut names: Vec<String> =
        RUN_OUTPUTS.iter().map(|n| n.to_string()).chain(meshes).chain([MEMBER_DIR.to_string()]).collect();
    names.retain(|n| out.join(n).exists());
    if let Ok(entries) = std::fs::read_dir(out) {
        names.extend(
            entries
                .flatten()
                .map(|e| e.file_name().to_string_lossy().to_string())
                .filter(|n| n.starts_with(SEED_MEMBER_PREFIX)),
        );
    }
    names
}

/// The trainer for `start`: `Resume("latest")` falls back to older checkpoints when the newest
/// cannot be read (e.g. a file cut short by a kill), saying so through `monitor`.
pub fn start_trainer(
    case: &Case,
    cfg: &Config,
    device: Device,
    out: &Path,
    start: Start,
    monitor: &mut dyn Monitor,
) -> Result<Trainer> {
    let ck_dir = out.join("checkpoints");
    match start {
        Start::Fresh if holds_run(out) => Err(CoreError::invalid(format!(
            "{} already holds a run: pass --resume to continue it or --overwrite to start again",
            out.display()
        ))),
        Start::Fresh => Trainer::new(case, cfg.clone(), device),
        Start::Overwrite => {
            // Everything an earlier run wrote here, and nothing else the folder may hold.
            for name in run_outputs_in(out) {
                remove_path(&out.join(name))?;
            }
            Trainer::new(case, cfg.clone(), device)
        }
        Start::Resume("latest") => {
            let mut first_error = None;
            for ck in Trainer::checkpoints(&ck_dir) {
                monitor.note(&format!("resuming from {}", ck.display()));
                match Trainer::resume(case, cfg.clone(), device.clone(), &ck) {
                    Ok(t) => return Ok(t),
                    Err(e) => {
                        monitor.note(&format!("warning: checkpoint {} is unusable: {e}", ck.display()));
                        first_error.get_or_insert(e);
                    }
                }
            }
            Err(match first_error {
                Some(e) => CoreError::invalid(format!("no usable checkpoint in {}: {e}", ck_dir.display())),
                None => CoreError::invalid(format!("no checkpoint in {}", ck_dir.display())),
            })
        }
        Start::Resume(path) => {
            if !Path::new(path).is_dir() {
                return Err(CoreError::invalid(format!(
                    "checkpoint `{path}` {}: pass a checkpoint folder (as `{}/ckpt-…`), or --resume alone for the \
                     newest one in the output folder",
                    if Path::new(path).exists() { "is not a folder" } else { "does not exist" },
                    ck_dir.display()
                )));
            }
            monitor.note(&format!("resuming from {path}"));
            Trainer::resume(case, cfg.clone(), device, Path::new(path))
        }
    }
}

/// Runs the optimisation of `case` with `cfg` on `device` (an autodiff device) in `out`:
/// checkpoints every `run.checkpoint_every` iterations and at the end, a checkpoint and
/// [`Outcome::Interrupted`] when the monitor asks to stop, otherwise the outputs and the report.
/// The members are trained next, each resumed from its own checkpoints: those of
/// `run.member_seeds` in `out/`[`seed_member_dir`], then with `run.prior_only_member` the
/// prior-only member in `out/`[`MEMBER_DIR`]; the outputs come from all of them.
pub fn run_completion(
    case: &Case,
    cfg: Config,
    device: Device,
    out: &Path,
    start: Start,
    monitor: &mut dyn Monitor,
) -> Result<Outcome> {
    // A run written into a case folder would mix outputs with inputs (and `--overwrite` would
    // then remove files beside the case's own).
    if out.join(CASE_FILE).exists() {
        return Err(CoreError::invalid(format!(
            "{} is a case folder (it holds {CASE_FILE}): write the run to a folder of its own",
            out.display()
        )));
    }
    // The arrival maps are read by the outputs only: a bad one is named before training.
    case.arrival_maps()?;
    // One process per run folder: a second one would mix its checkpoints and outputs in.
    let _lock = FolderLock::take(out, RUN_LOCK, "the run folder")?;
    // Files of a run's names that no run left (a user's own mesh.obj, say) would be
    // overwritten without a word.
    if matches!(start, Start::Fresh) && !holds_run(out) {
        let taken = run_outputs_in(out);
        if !taken.is_empty() {
            return Err(CoreError::invalid(format!(
                "{} holds {} but no run: a run would write over it; choose a new or empty folder, or pass \
                 --overwrite to replace what a run writes",
                out.display(),
                taken.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", ")
            )));
        }
    }
    let trainer = start_trainer(case, &cfg, device.clone(), out, start, monitor)?;
    let (trainer, warned) = match train(trainer, &cfg, out, monitor)? {
        Trained::Done { trainer, warned } => (*trainer, warned),
        Trained::Stopped(checkpoint) => return Ok(Outcome::Interrupted { checkpoint }),
    };
    let mut seed_members = Vec::new();
    for member_cfg in cfg.seed_members() {
        let dir = out.join(seed_member_dir(member_cfg.run.seed));
        let note = format!("the image-seeded member of seed {} (run.member_seeds)", member_cfg.run.seed);
        match train_member(case, &member_cfg, device.clone(), &dir, &note, monitor)? {
            Trained::Done { trainer, .. } => seed_members.push(*trainer),
            Trained::Stopped(checkpoint) => return Ok(Outcome::Interrupted { checkpoint }),
        }
    }
    let member = match cfg.prior_only_member() {
        Some(member_cfg) => {
            let dir = out.join(MEMBER_DIR);
            let note = "the prior-only member (run.prior_only_member: no image seeds)";
            match train_member(case, &member_cfg, device, &dir, note, monitor)? {
                Trained::Done { trainer, .. } => Some(*trainer),
                Trained::Stopped(checkpoint) => return Ok(Outcome::Interrupted { checkpoint }),
            }
        }
        None => None,
    };
    let run = RunModels { model: trainer, seed_members, prior_only: member, folder: out.to_path_buf() };
    let summary = write_outputs(out, case, &run, &[])?;
    if let Some(s) = summary.field_densities.filter(|_| summary.field_constant && !warned) {
        monitor.note(&collapse_warning(run.model.iteration(), s.p50));
    }
    for note in write_report(out)?.left_out {
        monitor.note(&format!("the report leaves out {note}"));
    }
    Ok(Outcome::Finished(Box::new(summary)))
}

/// Trains (or resumes, when `dir` holds its checkpoints) a member of a run in `dir`.
fn train_member(
    case: &Case,
    cfg: &Config,
    device: Device,
    dir: &Path,
    what: &str,
    monitor: &mut dyn Monitor,
) -> Result<Trained> {
    let start = if holds_run(dir) { Start::Resume("latest") } else { Start::Fresh };
    monitor.note(&format!("{what} in {}", dir.display()));
    std::fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
    let member = start_trainer(case, cfg, device, dir, start, monitor)?;
    train(member, cfg, dir, monitor)
}

/// Whether a training loop runs (then a stop request saves a checkpoint between steps; in
/// every other phase — initialisation, outputs, skeleton, report — there is nothing to save,
/// and a caller's signal handler may end the process at once).
static TRAINING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether a training loop of this process runs now (see `TRAINING`).
pub fn training_in_progress() -> bool {
    TRAINING.load(std::sync::atomic::Ordering::SeqCst)
}

/// Marks a training loop for its lifetime.
struct TrainingPhase;

impl TrainingPhase {
    fn start() -> Self {
        TRAINING.store(true, std::sync::atomic::Ordering::SeqCst);
        Self
    }
}

impl Drop for TrainingPhase {
    fn drop(&mut self) {
        TRAINING.store(false, std::sync::atomic::Ordering::SeqCst);
    }
}

/// How [`train`] ended.
enum Trained {
    /// All iterations done, the last checkpoint saved; `warned`: the collapse warning was given.
    Done { trainer: Box<Trainer>, warned: bool },
    /// Stopped on request after saving this checkpoint.
    Stopped(PathBuf),
}

/// Trains `trainer` to [`RunConfig::steps_to_train`](crate::config::RunConfig::steps_to_train)
/// (`run.iterations`, or a member's `run.member_iterations`), checkpointing into `out/checkpoints`.
fn train(mut trainer: Trainer, cfg: &Config, out: &Path, monitor: &mut dyn Monitor) -> Result<Trained> {
    let ck_dir = out.join("checkpoints");
    monitor.started(&trainer, cfg);
    let _phase = TrainingPhase::start();
    let mut warned = false;
    let until = cfg.run.steps_to_train();
    while trainer.iteration() < until {
        trainer.step()?;
        let logged = trainer.new_logs();
        monitor.stepped(&trainer, &logged);
        let every = cfg.run.checkpoint_every;
        if every > 0 && trainer.iteration().is_multiple_of(every) && trainer.iteration() < until {
            trainer.save_checkpoint(&ck_dir)?;
            warn_if_constant(&trainer, &mut warned, monitor);
        }
        if monitor.should_stop() {
            return Ok(Trained::Stopped(trainer.save_checkpoint(&ck_dir)?));
        }
    }
    trainer.save_checkpoint(&ck_dir)?;
    let logged = trainer.new_logs();
    if !logged.is_empty() {
        monitor.stepped(&trainer, &logged);
    }
    Ok(Trained::Done { trainer: Box::new(trainer), warned })
}

/// Tells the user, once per run, when the trained field gives every Gaussian the same density
/// (at periodic checkpoints; the end of the run reads it from the summary).
fn warn_if_constant(trainer: &Trainer, warned: &mut bool, monitor: &mut dyn Monitor) {
    if *warned || trainer.iteration() == 0 {
        return;
    }
    if let Some(s) = trainer.density_spread().filter(|s| s.is_constant()) {
        *warned = true;
        monitor.note(&collapse_warning(trainer.iteration(), s.p50));
    }
}

/// The warning for a field that gives every Gaussian the same `density` (per mm).
fn collapse_warning(iteration: usize, density: f32) -> String {
    format!(
        "warning: at iteration {iteration} the opacity field gives every Gaussian the same density \
         ({density:.4e} per mm): it has collapsed to a constant, so the densities no longer tell \
         vessels from background and density pruning cannot fire. With Adam, a coupled weight decay \
         on the field does this once the image gradients are small: try optim.field_weight_decay = 0"
    )
}
