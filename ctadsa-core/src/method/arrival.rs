//! The contrast's arrival time at a 3-D point in two views. A time-resolved biplane run images
//! the bolus in both planes at the same instants, so each pixel has the frame at which the first
//! vessel along its ray fills ([`crate::data::case::ViewEntry::arrival`]). A point on a vessel
//! fills at one time in both views; a ghost, which pairs one vessel's image in one view with
//! another's in the other, shows two different times. The image seeds
//! ([`crate::method::init::n2_seeds`], `init.arrival_seeds`) and the new centreline branches
//! ([`crate::output::arrival`]) are checked this way.

use ctadsa_render::ConeBeamView;
use glam::DVec3;

use crate::config::Config;
use crate::data::case::Case;
use crate::data::case::images::{Image, NO_ARRIVAL, bin_arrival};
use crate::data::masks::{prior_solid, silhouettes};
use crate::data::volume::Grid;
use crate::error::Result;

/// Value of a run's arrival-map pixel that the prior's projection covers, where
/// `init.arrival_prior_unknown` says the prior hides what fills behind it.
pub const HIDDEN_BY_PRIOR: f32 = -2.0;

/// The arrival maps of a run's views (its `run.views`, binned by `run.image_binning`: a binned
/// pixel keeps the earliest frame of its block), when the case has one for every view.
pub fn run_arrival_maps(case: &Case, cfg: &Config) -> Result<Option<Vec<Image>>> {
    let case = run_case(case, cfg)?;
    let Some(maps) = case.arrival_maps()? else { return Ok(None) };
    Ok(Some(maps.iter().map(|m| bin_arrival(m, cfg.run.image_binning.max(1))).collect()))
}

/// The case with only the run's views (`run.views`; all when empty).
pub(crate) fn run_case(case: &Case, cfg: &Config) -> Result<Case> {
    if cfg.run.views.is_empty() { Ok(case.clone()) } else { case.select_views(&cfg.run.views) }
}

/// The maps the seed checks read: [`run_arrival_maps`], and with `init.arrival_prior_unknown`
/// and a prior mesh the pixels of the prior's projection (voxelised at the case's voxel) set to
/// [`HIDDEN_BY_PRIOR`].
pub fn seed_arrival_maps(case: &Case, cfg: &Config) -> Result<Option<Vec<Image>>> {
    let Some(mut maps) = run_arrival_maps(case, cfg)? else { return Ok(None) };
    if !cfg.init.arrival_prior_unknown {
        return Ok(Some(maps));
    }
    let case = run_case(case, cfg)?;
    if let Some(prior) = case.prior_mesh()? {
        let b = cfg.run.image_binning.max(1);
        let views: Vec<ConeBeamView> =
            case.views.views().iter().map(|v| v.binned(b)).collect::<std::result::Result<_, _>>()?;
        let grid = Grid::covering(&case.file.volume.bounds(), case.file.volume.voxel_mm)?;
        let solid = prior_solid(&prior, grid);
        for (map, covered) in maps.iter_mut().zip(silhouettes(&solid, &views)) {
            if covered.data.len() == map.data.len() {
                for (px, &c) in map.data.iter_mut().zip(&covered.data) {
                    if c {
                        *px = HIDDEN_BY_PRIOR;
                    }
                }
            }
        }
    }
    Ok(Some(maps))
}

/// The frames of the 3 × 3 pixels around `view`'s projection of `p` (a pixel no vessel fills,
/// or off the detector, is [`NO_ARRIVAL`]).
pub fn frames_around(view: &ConeBeamView, map: &Image, p: DVec3) -> [f32; 9] {
    let mut out = [NO_ARRIVAL; 9];
    let Some(uv) = view.project(p) else { return out };
    let (u, v) = (uv.x.round() as i64, uv.y.round() as i64);
    for (k, slot) in out.iter_mut().enumerate() {
        let (c, r) = (u + k as i64 % 3 - 1, v + k as i64 / 3 - 1);
        if c >= 0 && r >= 0 && c < map.width as i64 && r < map.height as i64 {
            *slot = map.data[r as usize * map.width as usize + c as usize];
        }
    }
    out
}

/// Whether some filled pixel of `first` and some of `second` filled within `tolerance_frames`
/// of each other; a side whose pixels are all [`HIDDEN_BY_PRIOR`] or unfilled, at least one
/// hidden, cannot tell, and agrees with any side that has a filled or hidden pixel.
pub fn frames_agree(first: &[f32; 9], second: &[f32; 9], tolerance_frames: f32) -> bool {
    let filled = |f: &&f32| **f >= 0.0;
    let hidden = |s: &[f32; 9]| !s.iter().any(|f| filled(&f)) && s.contains(&HIDDEN_BY_PRIOR);
    let seen = |s: &[f32; 9]| s.iter().any(|&f| f >= 0.0 || f == HIDDEN_BY_PRIOR);
    if (hidden(first) && seen(second)) || (hidden(second) && seen(first)) {
        return true;
    }
    first.iter().filter(filled).any(|f| second.iter().filter(filled).any(|g| (f - g).abs() <= tolerance_frames))
}

/// Whether the point `p` fills at one time in both of two views (`maps[v]` the arrival map of
/// `views[v]`, the first two of each): some pixel of the 3 × 3 around each projection filled
/// within `tolerance_frames` of some around the other. A vessel behind an earlier-filled one in
/// a view (the prior's, say) shows that one's frame there and fails.
pub fn arrives_together(views: &[ConeBeamView], maps: &[Image], p: DVec3, tolerance_frames: f32) -> bool {
    frames_agree(&frames_around(&views[0], &maps[0], p), &frames_around(&views[1], &maps[1], p), tolerance_frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn around(frames: &[f32]) -> [f32; 9] {
        let mut out = [NO_ARRIVAL; 9];
        out[..frames.len()].copy_from_slice(frames);
        out
    }

    /// Frames agree within the tolerance; a side the prior hides agrees with any side that
    /// shows something, but not with one where nothing fills; a side with a filled pixel beside
    /// the prior's is judged by that pixel.
    #[test]
    fn a_side_hidden_by_the_prior_cannot_disagree() {
        let (three, five, hidden) = (around(&[3.0]), around(&[5.0, NO_ARRIVAL]), around(&[HIDDEN_BY_PRIOR]));
        assert!(frames_agree(&three, &around(&[3.0]), 0.0));
        assert!(!frames_agree(&three, &five, 0.0));
        assert!(frames_agree(&three, &five, 2.0));
        assert!(frames_agree(&hidden, &five, 0.0) && frames_agree(&five, &hidden, 0.0));
        assert!(frames_agree(&hidden, &hidden, 0.0));
        assert!(!frames_agree(&hidden, &[NO_ARRIVAL; 9], 0.0));
        assert!(!frames_agree(&around(&[HIDDEN_BY_PRIOR, 5.0]), &three, 0.0));
        assert!(frames_agree(&around(&[HIDDEN_BY_PRIOR, 3.0]), &three, 0.0));
    }
}
