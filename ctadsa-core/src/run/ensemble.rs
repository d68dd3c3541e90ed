//! An ensemble of finished runs of one case (`ctadsa ensemble`): each run's density as its own
//! outputs have it (its image-seeded models' mean, then with its prior-only member), the mean
//! over the runs, and from that mean the outputs a run writes — surface, centreline, metrics,
//! report — in a folder of their own. Runs of different budgets or configurations make
//! different errors; their mean keeps what they agree on (docs/RESULTS.md, "Ensembles across
//! budgets").

use std::path::{Path, PathBuf};

use burn::tensor::Device;

use super::completion::{
    MEMBER_DIR, Monitor, RUN_LOCK, Start, holds_checkpoints, run_outputs_in, seed_member_dir, start_trainer,
};
use crate::config::Config;
use crate::data::case::{CASE_FILE, Case};
use crate::error::{CoreError, Result, remove_path};
use crate::method::arrival::run_case;
use crate::method::train::Trainer;
use crate::output::export::{RunModels, RunSummary, write_outputs};
use crate::output::report::write_report;
use crate::run::lock::FolderLock;

/// The most runs one ensemble averages (each run's models are held in memory at once).
pub const MAX_ENSEMBLE_RUNS: usize = 16;

/// Averages the finished runs `runs` of `case` (folders that `ctadsa complete` finished, all of
/// the same views) and writes the outputs and the report into `out`; the first run gives the
/// configuration, the Gaussians and the renders written. `out` may not be one of the runs nor
/// hold a run's checkpoints; outputs of an earlier ensemble there are replaced with `overwrite`
/// and refused without. Nothing is trained: a run that is not finished is refused.
pub fn run_ensemble(
    case: &Case,
    runs: &[PathBuf],
    device: Device,
    out: &Path,
    overwrite: bool,
    monitor: &mut dyn Monitor,
) -> Result<RunSummary> {
    check_folders(runs, out)?;
    // The runs' configurations first (cheap): a run that is none, or of other views, is refused
    // before any folder is made or any model read.
    let configs = runs.iter().map(|run| run_config(run)).collect::<Result<Vec<_>>>()?;
    let views = |cfg: &Config| -> Result<Vec<String>> {
        Ok(run_case(case, cfg)?.file.views.iter().map(|v| v.name.clone()).collect())
    };
    let first = views(&configs[0])?;
    for (cfg, run) in configs.iter().zip(runs).skip(1) {
        let these = views(cfg)?;
        if these != first {
            return Err(CoreError::invalid(format!(
                "{} sees the views {these:?} and {} the views {first:?}: an ensemble averages runs of the same views",
                run.display(),
                runs[0].display()
            )));
        }
    }
    let _lock = FolderLock::take(out, RUN_LOCK, "the ensemble folder")?;
    let earlier = run_outputs_in(out);
    if !earlier.is_empty() {
        if !overwrite {
            return Err(CoreError::invalid(format!(
                "{} holds {}: an ensemble would write over it; choose a new or empty folder, or pass --overwrite",
                out.display(),
                earlier.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", ")
            )));
        }
        for name in earlier {
            remove_path(&out.join(name))?;
        }
    }
    let mut models = Vec::with_capacity(runs.len());
    for (run, cfg) in runs.iter().zip(&configs) {
        monitor.note(&format!("reading the finished run {}", run.display()));
        models.push(finished_run(case, run, cfg, device.clone(), monitor)?);
    }
    let summary = write_outputs(out, case, &models[0], &models[1..])?;
    for note in write_report(out)?.left_out {
        monitor.note(&format!("the report leaves out {note}"));
    }
    Ok(summary)
}

/// Refuses fewer than two runs or more than [`MAX_ENSEMBLE_RUNS`], a run named twice, a run
/// folder that does not exist, and an output folder that is a case, one of the runs, or a run.
fn check_folders(runs: &[PathBuf], out: &Path) -> Result<()> {
    if runs.len() < 2 || runs.len() > MAX_ENSEMBLE_RUNS {
        return Err(CoreError::invalid(format!(
            "an ensemble averages 2 to {MAX_ENSEMBLE_RUNS} runs; {} given",
            runs.len()
        )));
    }
    let mut seen: Vec<(PathBuf, &Path)> = Vec::new();
    for run in runs {
        let real = run.canonicalize().map_err(|e| CoreError::io(run, e))?;
        if let Some((_, other)) = seen.iter().find(|(p, _)| *p == real) {
            return Err(CoreError::invalid(format!(
                "{} and {} are the same run: name each run once",
                other.display(),
                run.display()
            )));
        }
        seen.push((real, run));
    }
    if out.join(CASE_FILE).exists() {
        return Err(CoreError::invalid(format!(
            "{} is a case folder (it holds {CASE_FILE}): write the ensemble to a folder of its own",
            out.display()
        )));
    }
    if let Some((_, run)) = out.canonicalize().ok().and_then(|o| seen.into_iter().find(|(p, _)| *p == o)) {
        return Err(CoreError::invalid(format!(
            "{} is one of the runs ({}): write the ensemble to a folder of its own",
            out.display(),
            run.display()
        )));
    }
    if holds_checkpoints(out) {
        return Err(CoreError::invalid(format!(
            "{} holds a run's checkpoints: write the ensemble to a folder of its own",
            out.display()
        )));
    }
    Ok(())
}

/// The configuration of the finished run in `folder` (its `config.toml`).
fn run_config(folder: &Path) -> Result<Config> {
    let config = folder.join("config.toml");
    if !config.is_file() {
        return Err(CoreError::invalid(format!(
            "{} is not a finished run (no config.toml): `ctadsa complete --out {} --resume` finishes one",
            folder.display(),
            folder.display()
        )));
    }
    Config::load(Some(&config), &[])
}

/// The models of the finished run in `folder`, trained with `cfg`: its own, its image-seeded
/// members and its prior-only member, each at the last step of its schedule.
fn finished_run(
    case: &Case,
    folder: &Path,
    cfg: &Config,
    device: Device,
    monitor: &mut dyn Monitor,
) -> Result<RunModels> {
    let model = finished_model(case, cfg, device.clone(), folder, monitor)?;
    let mut seed_members = vec![];
    for member in cfg.seed_members() {
        let dir = folder.join(seed_member_dir(member.run.seed));
        seed_members.push(finished_model(case, &member, device.clone(), &dir, monitor)?);
    }
    let prior_only = match cfg.prior_only_member() {
        Some(member) => Some(finished_model(case, &member, device, &folder.join(MEMBER_DIR), monitor)?),
        None => None,
    };
    Ok(RunModels { model, seed_members, prior_only, folder: folder.to_path_buf() })
}

/// The model trained with `cfg` in `dir`, read from its newest usable checkpoint; refused unless
/// that is the last step of `cfg`'s schedule.
fn finished_model(case: &Case, cfg: &Config, device: Device, dir: &Path, monitor: &mut dyn Monitor) -> Result<Trainer> {
    let trainer = start_trainer(case, cfg, device, dir, Start::Resume("latest"), monitor)?;
    let until = cfg.run.steps_to_train();
    if trainer.iteration() < until {
        return Err(CoreError::invalid(format!(
            "{} is not finished (its newest usable checkpoint is at step {} of {until}): `ctadsa complete --resume` \
             finishes it",
            dir.display(),
            trainer.iteration()
        )));
    }
    Ok(trainer)
}
