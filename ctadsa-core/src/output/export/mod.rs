//! Everything a completion run writes: density volume (NIfTI), completed mesh, Gaussians (PLY),
//! renders beside targets with their difference (PNG), loss curve (PNG + CSV), the config used,
//! and metrics (JSON) when the case has ground truth.

mod density;
mod gaussians;
mod pictures;
mod poses;
mod summary;
mod surface;
mod traced;

use std::path::Path;

use crate::data::case::Case;
use crate::data::mesh::io::write_mesh;
use crate::data::vessel_evidence::ViewReading;
use crate::data::volume::nifti_io::write_nifti;
use crate::error::{Result, to_json, write_file};
use crate::eval::score::{CaseTruth, EvalOptions};
use crate::method::arrival::{prior_hidden_maps, run_arrival_maps, run_arrival_readings, run_case};
use crate::method::training_time::TrainingTime;
use crate::output::confidence::mesh_without_doubtful;

pub use density::{RunModels, completion_density, density_volume, mc_level};
use gaussians::write_gaussians;
use pictures::{write_loss, write_mesh_pictures, write_renders};
use poses::write_poses;
pub use summary::{MemberSummary, RunSummary};
use surface::extract_completed_surface;
use traced::{traced_solid, write_centreline_of};

/// Writes the outputs of the run `own` into `dir`; with members (its `seed_members`, its
/// `prior_only` member) or further runs (`others`, an ensemble of finished runs of the same case
/// and views) the density, the surface and what comes from them are of the mean density
/// ([`completion_density`]); the configuration, the Gaussians, the renders and the loss are
/// `own`'s model's.
pub fn write_outputs(dir: &Path, case: &Case, own: &RunModels, others: &[RunModels]) -> Result<RunSummary> {
    let trainer = &own.model;
    let cfg = trainer.cfg();
    write_file(&dir.join("config.toml"), cfg.to_toml().as_bytes())?;
    let gaussians = write_gaussians(dir, trainer)?;
    let volume = completion_density(own, others)?;
    write_nifti(&dir.join("density.nii.gz"), &volume, "ctadsa density (per mm)")?;
    let prior = case.prior_mesh()?;
    let surface = extract_completed_surface(dir, trainer, &volume, prior.as_ref())?;
    let truth = CaseTruth::load(case)?;
    let traced = traced_solid(own, others, &volume, &surface, prior.as_ref())?;
    let arrival_maps = match cfg.output.arrival_prior_exit_px {
        Some(_) => prior_hidden_maps(case, cfg)?,
        None => run_arrival_maps(case, cfg)?,
    };
    let (centreline, topology, vertex_confidence) = write_centreline_of(
        dir,
        &volume,
        &surface,
        &traced,
        &cfg.output,
        trainer.views().views(),
        arrival_maps.as_deref(),
        truth.as_ref(),
    )?;
    let trusted;
    let mesh = if cfg.output.min_confidence > 0.0 {
        trusted = mesh_without_doubtful(&surface.mesh, &vertex_confidence, cfg.output.min_confidence);
        write_mesh(&dir.join(format!("mesh.{}", cfg.output.mesh_format)), &trusted)?;
        &trusted
    } else {
        &surface.mesh
    };
    let renders = trainer.render_all()?;
    write_renders(dir, case, trainer, &renders)?;
    write_loss(dir, trainer.history())?;
    write_mesh_pictures(dir, mesh, prior.as_ref())?;
    // Metrics.
    let options = EvalOptions { samples: cfg.output.metric_samples, ..EvalOptions::default() };
    let scored = truth.as_ref().map(|t| t.evaluate(mesh, &options));
    let prior_scored = match (&truth, &prior) {
        (Some(t), Some(p)) => Some(t.evaluate(p, &options)),
        _ => None,
    };
    let pose_errors = write_poses(dir, case, trainer, prior.as_ref())?;
    let spread = trainer.density_spread();
    let summary = RunSummary {
        case_dir: case.dir.display().to_string(),
        case_fingerprint: case.fingerprint(),
        iterations: trainer.iteration(),
        gaussians,
        n1: trainer.seed_counts().0,
        n2: trainer.seed_counts().1,
        mc_level: surface.level,
        level_scores: surface.level_scores,
        faint_level: surface.faint_level,
        mesh_triangles: mesh.faces.len(),
        islands_dropped: surface.islands_dropped,
        final_loss: trainer.history().last().map_or(f64::NAN, |s| s.loss),
        field_densities: spread,
        field_constant: spread.is_some_and(|s| s.is_constant()),
        training_time: TrainingTime::of(trainer.history()),
        prior_only_member: own.prior_only.as_ref().map(MemberSummary::of),
        seed_members: own.seed_members.iter().map(MemberSummary::of).collect(),
        ensemble_runs: match others {
            [] => vec![],
            _ => std::iter::once(own).chain(others).map(|run| run.folder.display().to_string()).collect(),
        },
        metrics: scored.as_ref().map(|r| r.scores),
        coverage: scored.as_ref().map(|r| r.coverage),
        paper_metrics: scored.as_ref().map(|r| r.paper),
        prior_metrics: prior_scored.as_ref().map(|r| r.scores),
        prior_coverage: prior_scored.as_ref().map(|r| r.coverage),
        centreline,
        topology,
        pose_errors,
        arrival_readings: run_arrival_readings(case, cfg)?,
        view_readings: ViewReading::of_run(
            trainer.images(),
            &run_case(case, cfg)?.file.views.iter().map(|entry| entry.name.as_str()).collect::<Vec<_>>(),
        ),
    };
    let summary_path = dir.join("summary.json");
    write_file(&summary_path, to_json(&summary, &summary_path)?.as_bytes())?;
    Ok(summary)
}
