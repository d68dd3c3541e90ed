//! `gaussians.ply`: the run's Gaussians.

use std::path::Path;

use crate::data::mesh::io::write_point_ply;
use crate::error::Result;
use crate::method::train::Trainer;

/// `gaussians.ply`: centres and scales (mm), quaternions, densities. Returns the count.
pub(super) fn write_gaussians(dir: &Path, trainer: &Trainer) -> Result<usize> {
    let (means, scales, rotations, densities) = trainer.host_gaussians();
    let rows: Vec<Vec<f32>> = (0..densities.len())
        .map(|i| {
            let mut r = means[3 * i..3 * i + 3].to_vec();
            r.extend_from_slice(&scales[3 * i..3 * i + 3]);
            r.extend_from_slice(&rotations[4 * i..4 * i + 4]);
            r.push(densities[i]);
            r
        })
        .collect();
    write_point_ply(
        &dir.join("gaussians.ply"),
        &["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "density"],
        &rows,
        "ctadsa Gaussians: centres and scales in mm, quaternion w x y z, density per mm",
    )?;
    Ok(densities.len())
}
