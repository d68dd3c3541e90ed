//! The contrast's arrival time at a 3-D point in two views. A time-resolved biplane run images
//! the bolus in both planes at the same instants, so each pixel has the frame at which the first
//! vessel along its ray fills ([`crate::data::case::ViewEntry::arrival`]). A point on a vessel
//! fills at one time in both views; a ghost, which pairs one vessel's image in one view with
//! another's in the other, shows two different times. The image seeds
//! ([`crate::method::init::n2_seeds`], `init.arrival_seeds`), the Gaussians that training grows
//! ([`ghosts_by_arrival`], `densify.arrival_prune`) and the new centreline branches
//! ([`crate::output::arrival`]) are checked this way.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use serde::Serialize;

use crate::config::{Config, RunConfig};
use crate::data::case::Case;
use crate::data::case::images::{Image, NO_ARRIVAL, arrival_noise, bin_arrival, median_arrival};
use crate::data::masks::{prior_solid, silhouettes};
use crate::data::volume::Grid;
use crate::error::Result;

/// Value of a run's arrival-map pixel that the prior's projection covers, where
/// `init.arrival_prior_unknown` says the prior hides what fills behind it.
pub const HIDDEN_BY_PRIOR: f32 = -2.0;

/// The arrival maps of a run's views (its `run.views`), when the case has one for every view:
/// each read through the median [`arrival_reading`] chooses ([`median_arrival`]), binned by
/// `run.image_binning` (a binned pixel keeps the earliest frame of its block), and each filled
/// pixel's frame f turned into the time it stands for, f + the view's
/// [`ViewEntry::arrival_offset_frames`](crate::data::case::ViewEntry::arrival_offset_frames)
/// (frames of the run's clock: the contrast came between that and one frame later).
pub fn run_arrival_maps(case: &Case, cfg: &Config) -> Result<Option<Vec<Image>>> {
    let case = run_case(case, cfg)?;
    let Some(maps) = case.arrival_maps()? else { return Ok(None) };
    let binning = cfg.run.image_binning.max(1);
    let timed = maps.iter().zip(&case.file.views).map(|(map, entry)| {
        let median_px = arrival_reading(map, &entry.name, &cfg.run).median_px;
        arrival_times(&bin_arrival(&median_arrival(map, median_px), binning), entry.arrival_offset_frames)
    });
    Ok(Some(timed.collect()))
}

/// How a run reads one view's arrival map (reported in `summary.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ArrivalReading {
    /// The view's name in the case.
    pub view: String,
    /// The map's [`arrival_noise`]: the share of its filled pixels whose frame differs from
    /// their 3 × 3 neighbours' median.
    pub noise: f64,
    /// The half-width (pixels) of the median it is read through; 0: as it is.
    pub median_px: u32,
}

/// The median an arrival map is read through: `run.arrival_median_px` when set, else 1 pixel
/// when the map's [`arrival_noise`] exceeds `run.arrival_noisy_share`, else none.
pub fn arrival_reading(map: &Image, view: &str, run: &RunConfig) -> ArrivalReading {
    let noise = arrival_noise(map);
    let median_px = match run.arrival_median_px {
        0 if noise > run.arrival_noisy_share => 1,
        px => px,
    };
    ArrivalReading { view: view.to_string(), noise, median_px }
}

/// [`arrival_reading`] of each of a run's views, when the case has an arrival map for every one.
pub fn run_arrival_readings(case: &Case, cfg: &Config) -> Result<Option<Vec<ArrivalReading>>> {
    let case = run_case(case, cfg)?;
    let Some(maps) = case.arrival_maps()? else { return Ok(None) };
    let readings = maps.iter().zip(&case.file.views).map(|(map, entry)| arrival_reading(map, &entry.name, &cfg.run));
    Ok(Some(readings.collect()))
}

/// An arrival map's frames as the times (frames of the run's clock) they stand for: each filled
/// pixel's frame plus `offset_frames`, how late the view's frames were taken
/// ([`ViewEntry::arrival_offset_frames`](crate::data::case::ViewEntry::arrival_offset_frames));
/// unfilled pixels stay as they are.
pub fn arrival_times(map: &Image, offset_frames: f64) -> Image {
    let mut map = map.clone();
    map.data.iter_mut().filter(|f| **f >= 0.0).for_each(|f| *f += offset_frames as f32);
    map
}

/// The case with only the run's views (`run.views`; all when empty).
pub(crate) fn run_case(case: &Case, cfg: &Config) -> Result<Case> {
    if cfg.run.views.is_empty() { Ok(case.clone()) } else { case.select_views(&cfg.run.views) }
}

/// The maps the seed checks read: [`run_arrival_maps`], and with `init.arrival_prior_unknown`
/// the prior's projection hidden ([`prior_hidden_maps`]).
pub fn seed_arrival_maps(case: &Case, cfg: &Config) -> Result<Option<Vec<Image>>> {
    if cfg.init.arrival_prior_unknown { prior_hidden_maps(case, cfg) } else { run_arrival_maps(case, cfg) }
}

/// [`run_arrival_maps`] with the pixels of the prior's projection (the prior mesh voxelised at
/// the case's voxel) set to [`HIDDEN_BY_PRIOR`]; as they are when the case has no prior mesh.
pub fn prior_hidden_maps(case: &Case, cfg: &Config) -> Result<Option<Vec<Image>>> {
    let Some(mut maps) = run_arrival_maps(case, cfg)? else { return Ok(None) };
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

/// The pixel (column, row) `view` projects `p` into; it may lie off the detector.
fn pixel_of(view: &ConeBeamView, p: DVec3) -> Option<(i64, i64)> {
    view.project(p).map(|uv| (uv.x.round() as i64, uv.y.round() as i64))
}

/// The frames of the 3 × 3 pixels around the pixel `(u, v)` of `map` (a pixel no vessel fills,
/// or off the detector, is [`NO_ARRIVAL`]).
fn frames_at(map: &Image, (u, v): (i64, i64)) -> [f32; 9] {
    let mut out = [NO_ARRIVAL; 9];
    for (k, slot) in out.iter_mut().enumerate() {
        let (c, r) = (u + k as i64 % 3 - 1, v + k as i64 / 3 - 1);
        if c >= 0 && r >= 0 && c < map.width as i64 && r < map.height as i64 {
            *slot = map.data[r as usize * map.width as usize + c as usize];
        }
    }
    out
}

/// Whether a point's pixels in a view (the 3 × 3 of [`frames_at`]) lie wholly in the prior's
/// projection: all [`HIDDEN_BY_PRIOR`] or unfilled, at least one hidden.
fn hidden(frames: &[f32]) -> bool {
    !frames.iter().any(|&f| f >= 0.0) && frames.contains(&HIDDEN_BY_PRIOR)
}

/// Whether some filled pixel of `first` and some of `second` filled within `tolerance_frames`
/// of each other: a pixel's value t ([`run_arrival_maps`]: its frame plus its view's offset)
/// says the contrast came between t and t + 1, so two agree when those spans lie less than
/// `tolerance_frames` apart, |t − s| < 1 + `tolerance_frames` (whole frames of views imaged at
/// the same instants: the same frame at tolerance 0). A side whose pixels are all
/// [`HIDDEN_BY_PRIOR`] or unfilled, at least one hidden, cannot tell, and agrees with any side
/// that has a filled or hidden pixel.
pub fn frames_agree(first: &[f32], second: &[f32], tolerance_frames: f32) -> bool {
    let filled = |f: &&f32| **f >= 0.0;
    let seen = |s: &[f32]| s.iter().any(|&f| f >= 0.0 || f == HIDDEN_BY_PRIOR);
    if (hidden(first) && seen(second)) || (hidden(second) && seen(first)) {
        return true;
    }
    let within = 1.0 + tolerance_frames;
    first.iter().filter(filled).any(|f| second.iter().filter(filled).any(|g| (f - g).abs() < within))
}

/// The frames a view shows for a point ([`frames_seen`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Seen {
    /// The 3 × 3 pixels around its projection (off the detector: all [`NO_ARRIVAL`]).
    Around([f32; 9]),
    /// Where those lie wholly in the prior's projection, the frames filled in the window around
    /// it, outside the prior's projection.
    Exit(Vec<f32>),
}

impl std::ops::Deref for Seen {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        match self {
            Seen::Around(frames) => frames,
            Seen::Exit(frames) => frames,
        }
    }
}

/// The frames `view` shows for the point `p`: the 3 × 3 pixels around its projection, or, where those
/// lie wholly in the prior's projection and `exit_px` > 0, the filled pixels within `exit_px`
/// pixels (a square) of the projection, outside the prior's: where a vessel behind the prior
/// leaves its projection, it shows its own frame (none filled there: the 3 × 3, which cannot tell).
/// Allocates only for the window.
pub fn frames_seen(view: &ConeBeamView, map: &Image, p: DVec3, exit_px: u32) -> Seen {
    let Some((u, v)) = pixel_of(view, p) else { return Seen::Around([NO_ARRIVAL; 9]) };
    let near = frames_at(map, (u, v));
    if exit_px == 0 || !hidden(&near) {
        return Seen::Around(near);
    }
    let (r, w, h) = (exit_px as i64, map.width as i64, map.height as i64);
    let mut out = Vec::new();
    for row in (v - r).max(0)..(v + r + 1).min(h) {
        for col in (u - r).max(0)..(u + r + 1).min(w) {
            let f = map.data[(row * w + col) as usize];
            if f >= 0.0 {
                out.push(f);
            }
        }
    }
    if out.is_empty() { Seen::Around(near) } else { Seen::Exit(out) }
}

/// Whether the point `p` fills at one time in both of two views (`maps[v]` the arrival map of
/// `views[v]`, the first two of each): some pixel of the 3 × 3 around each projection filled
/// within `tolerance_frames` of some around the other ([`frames_seen`] with `exit_px`). A vessel
/// behind an earlier-filled one in a view (the prior's, say) shows that one's frame there and fails.
pub fn arrives_together(views: &[ConeBeamView], maps: &[Image], p: DVec3, tolerance_frames: f32, exit_px: u32) -> bool {
    frames_agree(
        &frames_seen(&views[0], &maps[0], p, exit_px),
        &frames_seen(&views[1], &maps[1], p, exit_px),
        tolerance_frames,
    )
}

/// Which of the points `centres` (mm) are ghosts by arrival: farther than a voxel of `prior` from
/// it (`None`: no prior) and not filling at once in both views ([`arrives_together`] on the two
/// views' `maps`, within `tolerance_frames`, the prior's exit window `exit_px`). The points
/// beside the prior are left alone: the prior's own Gaussians lie in its projection in both views.
pub fn ghosts_by_arrival(
    views: &[ConeBeamView],
    maps: &[Image],
    prior: Option<&crate::data::volume::Volume<u8>>,
    centres: &[DVec3],
    tolerance_frames: f32,
    exit_px: u32,
) -> Vec<bool> {
    use rayon::prelude::*;
    let beside_prior = |p: DVec3| {
        prior.is_some_and(|solid| {
            let h = solid.grid.spacing_mm;
            (0..27).any(|k| {
                let d = DVec3::new((k % 3) as f64 - 1.0, ((k / 3) % 3) as f64 - 1.0, (k / 9) as f64 - 1.0);
                solid.is_set_at(p + d * DVec3::from(h))
            })
        })
    };
    centres
        .par_iter()
        .map(|&p| p.is_finite() && !beside_prior(p) && !arrives_together(views, maps, p, tolerance_frames, exit_px))
        .collect()
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

    /// A point deep in the prior's projection: with `exit_px` it is judged by the frame filled
    /// where the vessel leaves the projection (4 px away); a window that ends inside the
    /// projection cannot tell.
    #[test]
    fn a_hidden_side_shows_the_frame_where_the_vessel_leaves_the_prior() {
        use ctadsa_render::TigreGeometry;
        let mut g = TigreGeometry::reference(0.0);
        g.detector_px = [64, 64];
        g.pixel_mm = [1.0, 1.0];
        let view = ConeBeamView::from_tigre(&g).unwrap();
        let p = DVec3::ZERO;
        let uv = view.project(p).unwrap();
        let (u, v) = (uv.x.round() as usize, uv.y.round() as usize);
        let mut map = Image { width: 64, height: 64, data: vec![NO_ARRIVAL; 64 * 64] };
        for r in v - 3..=v + 3 {
            for c in u - 3..=u + 3 {
                map.data[r * 64 + c] = HIDDEN_BY_PRIOR;
            }
        }
        map.data[v * 64 + u + 4] = 3.0;
        map.data[v * 64 + u + 10] = 5.0;
        let (three, five) = (around(&[3.0]), around(&[5.0]));
        let inside = frames_seen(&view, &map, p, 0);
        assert!(hidden(&inside) && frames_agree(&inside, &five, 0.0));
        assert_eq!(frames_seen(&view, &map, p, 2), inside, "the window ends inside the projection");
        let exit = frames_seen(&view, &map, p, 5);
        assert_eq!(exit, Seen::Exit(vec![3.0]));
        assert!(frames_agree(&exit, &three, 0.0) && !frames_agree(&exit, &five, 0.0));
        assert_eq!(frames_seen(&view, &map, p, 10), Seen::Exit(vec![3.0, 5.0]));
    }

    /// Points along a vessel fill at once in both views and stay; points along a ghost where
    /// two vessels' back-projections cross fill at two times and go, unless the prior lies
    /// within a voxel of them.
    #[test]
    fn ghosts_by_arrival_are_the_points_off_the_prior_that_fill_at_two_times() {
        use crate::data::volume::{Grid, Volume};
        use crate::method::init::tests::{CROSSING_GHOSTS, FILLED_A, opposite_fills};
        let (views, _, maps, bounds) = opposite_fills();
        let along = |(a, b): ([f64; 3], [f64; 3])| -> Vec<DVec3> {
            (0..=40).map(|k| DVec3::from(a).lerp(DVec3::from(b), 0.1 + 0.8 * k as f64 / 40.0)).collect()
        };
        let share = |flags: &[bool]| flags.iter().filter(|&&g| g).count() as f64 / flags.len() as f64;
        let (vessel, ghost) = (along(FILLED_A), along(CROSSING_GHOSTS[0]));
        let on_vessel = ghosts_by_arrival(&views, &maps, None, &vessel, 0.0, 0);
        let on_ghost = ghosts_by_arrival(&views, &maps, None, &ghost, 0.0, 0);
        assert!(share(&on_vessel) <= 0.05, "vessel points called ghosts: {:.2}", share(&on_vessel));
        // Halfway up both vessels fill in the same frames: a ghost there cannot be told.
        assert!(share(&on_ghost) >= 0.7, "ghost points called ghosts: {:.2}", share(&on_ghost));
        // A prior voxel beside every ghost point (0.4 mm voxels, the points 0.3 mm off) keeps them.
        let grid = Grid::covering(&bounds, 0.4).unwrap();
        let mut solid = Volume::<u8>::zeros(grid);
        for p in &ghost {
            let i = grid.index_at(*p + DVec3::new(0.3, 0.0, 0.0)).unwrap();
            solid.data[i] = 1;
        }
        assert!(ghosts_by_arrival(&views, &maps, Some(&solid), &ghost, 0.0, 0).iter().all(|g| !g));
        // A far prior changes nothing; a point that is not finite is left to the other prunes.
        let far = Volume::<u8>::zeros(grid);
        assert_eq!(ghosts_by_arrival(&views, &maps, Some(&far), &ghost, 0.0, 0), on_ghost);
        assert_eq!(ghosts_by_arrival(&views, &maps, None, &[DVec3::NAN], 0.0, 0), vec![false]);
    }
}
