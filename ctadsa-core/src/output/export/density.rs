//! The run's density on a grid: its own model's, or the mean over its members'.

use burn::module::Module;

use crate::data::volume::{Grid, Volume};
use crate::error::Result;
use crate::method::train::Trainer;
use crate::output::extraction::density_scale;
use ctadsa_ops::readback::host_vec;

/// The density field on a grid over the working box.
pub fn density_volume(trainer: &Trainer) -> Result<Volume<f32>> {
    let voxel = if trainer.cfg().output.voxel_mm > 0.0 { trainer.cfg().output.voxel_mm } else { trainer.voxel_mm() };
    density_on(trainer, Grid::covering(trainer.working_box(), voxel)?)
}

/// The density field of `trainer`'s Gaussians on `grid`.
pub(super) fn density_on(trainer: &Trainer, grid: Grid) -> Result<Volume<f32>> {
    let m = trainer.model().valid();
    let vol = ctadsa_render::voxelize(&m.gaussians(), &grid.to_render_grid()?, trainer.settings())?;
    Ok(Volume { grid, index_to_world: grid.index_to_world(), data: host_vec(vol) })
}

/// The density of the run: the mean of the image-seeded models' densities (the run's and its
/// `seed_members'`, `run.member_seeds`) on the run's grid, and with a prior-only `member`
/// (`run.prior_only_member`) the mean of that and the member's.
pub fn completion_density(
    trainer: &Trainer,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
) -> Result<Volume<f32>> {
    completion_density_on(density_volume(trainer)?, seed_members, member)
}

/// [`completion_density`] with the run's own density (on the grid it is to have) given.
pub(super) fn completion_density_on(
    mut volume: Volume<f32>,
    seed_members: &[Trainer],
    member: Option<&Trainer>,
) -> Result<Volume<f32>> {
    let mut seeded = vec![];
    for m in seed_members {
        seeded.push(density_on(m, volume.grid)?.data);
    }
    mean_into(&mut volume.data, &seeded);
    if let Some(member) = member {
        mean_into(&mut volume.data, &[density_on(member, volume.grid)?.data]);
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
