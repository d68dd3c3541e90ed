//! The run's density on a grid: its own model's, the mean over its members', or the mean over
//! the runs of an ensemble.

use std::path::{Path, PathBuf};

use burn::module::Module;

use crate::data::volume::{Grid, Volume};
use crate::error::Result;
use crate::method::train::Trainer;
use crate::output::extraction::density_scale;
use ctadsa_ops::readback::host_vec;

/// The trained models of one run: its own model, its further image-seeded members
/// (`run.member_seeds`) and its prior-only member (`run.prior_only_member`).
pub struct RunModels {
    /// The run's own model.
    pub model: Trainer,
    /// The further image-seeded members, in the order of `run.member_seeds`.
    pub seed_members: Vec<Trainer>,
    /// The prior-only member.
    pub prior_only: Option<Trainer>,
    /// The run's folder.
    pub folder: PathBuf,
}

impl RunModels {
    /// A run of one model alone, trained in `folder`.
    pub fn alone(model: Trainer, folder: &Path) -> Self {
        Self { model, seed_members: vec![], prior_only: None, folder: folder.to_path_buf() }
    }
}

/// The grid the outputs are written on: `output.voxel_mm` over the working box, or the
/// model's own voxel.
pub(super) fn output_grid(trainer: &Trainer) -> Result<Grid> {
    let voxel = if trainer.cfg().output.voxel_mm > 0.0 { trainer.cfg().output.voxel_mm } else { trainer.voxel_mm() };
    Grid::covering(trainer.working_box(), voxel)
}

/// The density field on a grid over the working box (`output.voxel_mm`, or the model's own voxel).
pub fn density_volume(trainer: &Trainer) -> Result<Volume<f32>> {
    density_on(trainer, output_grid(trainer)?)
}

/// The density field of `trainer`'s Gaussians on `grid`.
pub(super) fn density_on(trainer: &Trainer, grid: Grid) -> Result<Volume<f32>> {
    let m = trainer.model().valid();
    let vol = ctadsa_render::voxelize(&m.gaussians(), &grid.to_render_grid()?, trainer.settings())?;
    Ok(Volume { grid, index_to_world: grid.index_to_world(), data: host_vec(vol) })
}

/// The density of a completion on `own`'s output grid: each run's — the mean of its image-seeded
/// models' densities (its own model's and its `seed_members'`), and with a prior-only member the
/// mean of that and the member's — and with further runs (`others`, an ensemble) the mean over
/// the runs.
pub fn completion_density(own: &RunModels, others: &[RunModels]) -> Result<Volume<f32>> {
    completion_density_on(output_grid(&own.model)?, own, others)
}

/// [`completion_density`] on `grid`.
pub(super) fn completion_density_on(grid: Grid, own: &RunModels, others: &[RunModels]) -> Result<Volume<f32>> {
    let mut volume = run_density_on(grid, own)?;
    let others = others.iter().map(|run| run_density_on(grid, run).map(|v| v.data)).collect::<Result<Vec<_>>>()?;
    mean_into(&mut volume.data, &others);
    Ok(volume)
}

/// The density of one run on `grid` (see [`completion_density`]).
fn run_density_on(grid: Grid, run: &RunModels) -> Result<Volume<f32>> {
    let mut volume = density_on(&run.model, grid)?;
    let mut seeded = vec![];
    for m in &run.seed_members {
        seeded.push(density_on(m, grid)?.data);
    }
    mean_into(&mut volume.data, &seeded);
    if let Some(member) = &run.prior_only {
        mean_into(&mut volume.data, &[density_on(member, grid)?.data]);
    }
    Ok(volume)
}

/// `acc` becomes the voxel-wise mean of itself and `others` (each as long as `acc`).
pub(super) fn mean_into(acc: &mut [f32], others: &[Vec<f32>]) {
    if others.is_empty() {
        return;
    }
    let n = (others.len() + 1) as f32;
    for (i, d) in acc.iter_mut().enumerate() {
        *d = (*d + others.iter().map(|o| o[i]).sum::<f32>()) / n;
    }
}

/// The iso-level: relative to the 99.9th percentile of the positive densities, or absolute.
pub fn mc_level(volume: &Volume<f32>, level: f64, relative: bool) -> f64 {
    if relative { level * density_scale(volume) } else { level }
}
