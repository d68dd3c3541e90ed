//! Image seeds tracked along the vessels that leave the prior, one step at a time.
//!
//! With two views most of the back-projection's supported voxels are ghosts (a vessel of one
//! view meets every vessel of the other on its epipolar line). A vessel, though, is a smooth
//! curve that leaves the tree and keeps its look in each view. A track starts at a supported
//! voxel beside the prior, heading away from it, and steps [`STEP_MM`] at a time along the
//! direction — within [`CONE_DEG`] of the way it came — whose look-ahead both views show best,
//! less a cost for a turn either view sees and for a change of either view's brightness (where
//! a track would slip onto a ghost, one view's projection turns onto another vessel). A pixel
//! shows one vessel at one depth, so each track claims its pixels, and a track that runs on
//! pixels another claimed at another depth for longer than a crossing stops there. With the
//! views' arrival maps a claim whose point fills at two times (a ghost's) gives way to a point
//! that fills at once.
//!
//! The branches of a new vessel never touch the prior, so tracking may go in rounds: each round
//! after the first starts tracks beside the tracks of the round before, heading away from them.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};

use ctadsa_render::ConeBeamView;
use glam::{DVec3, IVec3};

use crate::data::case::images::Image;
use crate::data::masks::pixel_of;
use crate::data::volume::edt::squared_edt;
use crate::data::volume::{Grid, Volume};
use crate::method::init::Scored;

/// Step along a track (mm).
pub(crate) const STEP_MM: f64 = 0.5;
/// Look-ahead that scores a direction (mm).
const AHEAD_MM: f64 = 2.0;
/// Look-ahead that scores a track's first direction (mm).
const START_AHEAD_MM: f64 = 3.0;
/// Largest turn per step (degrees).
const CONE_DEG: f64 = 35.0;
/// A track ends within this distance (mm) of another track.
const MERGE_MM: f64 = 0.7;
/// A branch (a track of a later round) starts at a supported voxel at most this far (mm) from
/// the tracks of the round before (and farther than [`MERGE_MM`]).
const BRANCH_START_MM: f64 = 1.5;
/// A branch's first direction lies within 60° of the way away from the nearest track point.
const BRANCH_AWAY_COS: f64 = 0.5;
/// A claim is another vessel's when it lies farther than this (mm) from the track.
const CLAIM_TOLERANCE_MM: f64 = 1.5;
/// Longest track (mm).
const MAX_TRACK_MM: f64 = 150.0;
/// Directions tried per step (spread over the sphere).
const DIRECTIONS: usize = 400;
/// Brightness (residual over the vessel level) is capped here: one bright pixel does not carry
/// a look-ahead.
const MAX_BRIGHTNESS: f64 = 3.0;

/// Residual images with their vessel levels, sampled bilinearly at world points.
pub(crate) struct Residuals<'a> {
    pub views: &'a [ConeBeamView],
    /// What each view shows that the prior does not (contrast × mm).
    pub images: &'a [Image],
    /// Each view's vessel level (contrast × mm): brightness 1.
    pub levels: &'a [f64],
}

/// Bilinear sample at pixel position `(u, v)` (pixel centres at integers); 0 off the image.
fn bilinear(img: &Image, u: f64, v: f64) -> f64 {
    let (w, h) = (img.width as i64, img.height as i64);
    let (u0, v0) = (u.floor(), v.floor());
    let (fu, fv) = (u - u0, v - v0);
    let (u0, v0) = (u0 as i64, v0 as i64);
    let at = |c: i64, r: i64| {
        if c < 0 || r < 0 || c >= w || r >= h { 0.0 } else { img.data[(r * w + c) as usize] as f64 }
    };
    (1.0 - fv) * ((1.0 - fu) * at(u0, v0) + fu * at(u0 + 1, v0))
        + fv * ((1.0 - fu) * at(u0, v0 + 1) + fu * at(u0 + 1, v0 + 1))
}

impl Residuals<'_> {
    /// View `vi`'s brightness at `p` (residual over the vessel level, within ±[`MAX_BRIGHTNESS`]);
    /// 0 off its detector.
    fn brightness(&self, vi: usize, p: DVec3) -> f64 {
        self.views[vi].project(p).map_or(0.0, |uv| {
            (bilinear(&self.images[vi], uv.x, uv.y) / self.levels[vi]).clamp(-MAX_BRIGHTNESS, MAX_BRIGHTNESS)
        })
    }

    /// The mean over `len_mm` ahead of `p` along `d` (every [`STEP_MM`]) of the smaller of the
    /// views' brightness; each view's own mean goes to `per_view` (one per view), from the same
    /// samples.
    fn look_ahead(&self, p: DVec3, d: DVec3, len_mm: f64, per_view: &mut [f64]) -> f64 {
        let n = (len_mm / STEP_MM).round().max(1.0) as usize;
        per_view.fill(0.0);
        let mut smaller = 0.0;
        for k in 1..=n {
            let q = p + d * (k as f64 * STEP_MM);
            let mut least = f64::INFINITY;
            for (vi, sum) in per_view.iter_mut().enumerate() {
                let b = self.brightness(vi, q);
                *sum += b;
                least = least.min(b);
            }
            smaller += least;
        }
        per_view.iter_mut().for_each(|v| *v /= n as f64);
        smaller / n as f64
    }

    /// The largest, over the views, of 1 − cos of the angle between the projections of the
    /// directions `d` and `c` at `p` (0: no view sees a turn; a view that sees either end-on
    /// does not count).
    fn turn(&self, p: DVec3, d: DVec3, c: DVec3) -> f64 {
        let mut worst: f64 = 0.0;
        for view in self.views {
            let (Some(a), Some(b), Some(e)) = (view.project(p), view.project(p + d), view.project(p + c)) else {
                continue;
            };
            let (u, w) = (b - a, e - a);
            let n = u.length() * w.length();
            if n > 0.25 {
                worst = worst.max(1.0 - u.dot(w) / n);
            }
        }
        worst
    }
}

/// Unit directions spread evenly over the sphere (a Fibonacci lattice).
fn sphere_directions(n: usize) -> Vec<DVec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            DVec3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect()
}

/// Track points on a hashed grid of [`MERGE_MM`]-sized cells.
#[derive(Default)]
struct PointIndex {
    cells: HashMap<IVec3, Vec<(DVec3, usize)>>,
}

impl PointIndex {
    fn cell(p: DVec3) -> IVec3 {
        (p / MERGE_MM).floor().as_ivec3()
    }

    fn insert(&mut self, p: DVec3, track: usize) {
        self.cells.entry(Self::cell(p)).or_default().push((p, track));
    }

    /// The nearest point within `r_mm` of `p`, if any.
    fn nearest(&self, p: DVec3, r_mm: f64) -> Option<DVec3> {
        let (c, k) = (Self::cell(p), (r_mm / MERGE_MM).ceil() as i32);
        let mut best: Option<(f64, DVec3)> = None;
        for dx in -k..=k {
            for dy in -k..=k {
                for dz in -k..=k {
                    for &(q, _) in self.cells.get(&(c + IVec3::new(dx, dy, dz))).into_iter().flatten() {
                        let d = q.distance(p);
                        if d <= r_mm && best.is_none_or(|b| d < b.0) {
                            best = Some((d, q));
                        }
                    }
                }
            }
        }
        best.map(|b| b.1)
    }

    /// Whether a point of a track other than `skip` lies within [`MERGE_MM`] of `p`.
    fn near(&self, p: DVec3, skip: Option<usize>) -> bool {
        let c = Self::cell(p);
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    self.cells.get(&(c + IVec3::new(dx, dy, dz))).is_some_and(|ps| {
                        ps.iter().any(|&(q, t)| Some(t) != skip && q.distance_squared(p) < MERGE_MM * MERGE_MM)
                    })
                })
            })
        })
    }
}

/// A track's start, best look-ahead first.
struct Start {
    score: f64,
    p: DVec3,
    d: DVec3,
}

impl PartialEq for Start {
    fn eq(&self, o: &Self) -> bool {
        self.score.total_cmp(&o.score) == Ordering::Equal
    }
}
impl Eq for Start {}
impl PartialOrd for Start {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Start {
    fn cmp(&self, o: &Self) -> Ordering {
        self.score.total_cmp(&o.score)
    }
}

/// How tracks start, go on and stop (`init.track_*`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct TrackSettings {
    /// Tracks start at supported voxels at most this far (mm) from the prior.
    pub start_mm: f64,
    /// A track goes on while its best direction's score — the look-ahead's mean brightness
    /// (the smaller of the views', over their vessel levels) less its costs — is at least this.
    pub level: f64,
    /// Score lost per unit of 1 − cos of the largest turn a view sees.
    pub turn_cost: f64,
    /// Score lost per unit of |ln| change of a view's brightness from the track's so far.
    pub brightness_cost: f64,
    /// A track ends after this long (mm) on pixels another track claimed at another depth;
    /// 0 = no claims.
    pub claimed_run_mm: f64,
    /// Most points over all tracks.
    pub max_points: usize,
    /// Rounds: the first starts beside the prior, each further one beside the round before.
    pub rounds: usize,
}

/// Whether both views fill at once at a point (their arrival maps, `crate::method::arrival`).
pub(crate) type FillsAtOnce<'a> = &'a (dyn Fn(DVec3) -> bool + 'a);

/// Points (mm, every [`STEP_MM`]) of the vessels tracked away from the `prior` solid, started
/// at the `candidates` near it, and in later rounds (`settings.rounds`) at those near the
/// tracks of the round before. With `fills_at_once`, a claim whose point fills at two times (a
/// ghost's, likely) gives way to a point that fills at once: that point is not on claimed pixels.
pub(crate) fn track_from_prior(
    res: &Residuals,
    candidates: &[Scored],
    prior: &Volume<u8>,
    settings: TrackSettings,
    fills_at_once: Option<FillsAtOnce>,
) -> Vec<DVec3> {
    let dist2 = squared_edt(&prior.map(|v| u8::from(v == 0)));
    let prior_dist = |p: DVec3| prior.grid.index_at(p).map_or(f64::INFINITY, |i| dist2[i].sqrt());
    let tracker = Tracker {
        res,
        settings,
        grid: prior.grid,
        dirs: sphere_directions(DIRECTIONS),
        cos_cone: CONE_DEG.to_radians().cos(),
        fills_at_once,
    };
    let mut tracks = Tracks::default();
    let mut starts = tracker.starts(candidates, |p| {
        let d0 = prior_dist(p);
        (d0 <= settings.start_mm).then_some(move |q: DVec3| prior_dist(q) > d0 + 1.0)
    });
    let mut round_begin = 0;
    for round in 0..settings.rounds.max(1) {
        if round > 0 {
            // Branches start beside the tracks of the round before, heading away from them.
            if round_begin == tracks.points.len() {
                break; // the round before found nothing
            }
            let mut last = PointIndex::default();
            tracks.points[round_begin..].iter().for_each(|&p| last.insert(p, 0));
            round_begin = tracks.points.len();
            starts = tracker.starts(candidates, |p| {
                let q = last.nearest(p, BRANCH_START_MM).filter(|q| q.distance(p) > MERGE_MM)?;
                let away = (p - q).normalize();
                Some(move |r: DVec3| (r - p).normalize().dot(away) > BRANCH_AWAY_COS && prior_dist(r) > 0.0)
            });
        }
        tracker.follow(std::mem::take(&mut starts), &prior_dist, &mut tracks);
        if tracks.points.len() >= settings.max_points {
            break;
        }
    }
    tracks.points
}

/// What every track reads: the views, the settings, the prior's grid, the directions tried and
/// the views' arrival check, if any.
struct Tracker<'a> {
    res: &'a Residuals<'a>,
    settings: TrackSettings,
    grid: Grid,
    dirs: Vec<DVec3>,
    cos_cone: f64,
    fills_at_once: Option<FillsAtOnce<'a>>,
}

/// A track point's claim on a pixel (a pixel shows one vessel at one depth).
#[derive(Clone, Copy)]
struct Claim {
    point: DVec3,
    track: usize,
    /// Whether both views fill at once at the point (without an arrival check: true).
    fills_at_once: bool,
}

/// The tracks so far: their points, a spatial index of them and their pixels' claims.
#[derive(Default)]
struct Tracks {
    points: Vec<DVec3>,
    index: PointIndex,
    /// (view, pixel) → the claim on it.
    claims: HashMap<(usize, usize), Claim>,
    count: usize,
}

impl Tracker<'_> {
    /// The starts among the `candidates`, best look-ahead first: `allowed(p)` says whether a
    /// track may start at `p` and, if so, which points 2 mm ahead count as heading away.
    fn starts<F: Fn(DVec3) -> bool>(
        &self,
        candidates: &[Scored],
        allowed: impl Fn(DVec3) -> Option<F>,
    ) -> BinaryHeap<Start> {
        let mut starts = BinaryHeap::new();
        let mut scratch = vec![0.0; self.res.views.len()];
        for s in candidates {
            let Some(away) = allowed(s.1) else { continue };
            let best = self
                .dirs
                .iter()
                .filter(|&&d| away(s.1 + d * 2.0))
                .map(|&d| (self.res.look_ahead(s.1, d, START_AHEAD_MM, &mut scratch), d))
                .max_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((score, d)) = best.filter(|b| b.0 >= self.settings.level) {
                starts.push(Start { score, p: s.1, d });
            }
        }
        starts
    }

    /// Follows a track from each of the `starts` (best first) that no track has reached yet.
    fn follow(&self, mut starts: BinaryHeap<Start>, prior_dist: &impl Fn(DVec3) -> f64, tracks: &mut Tracks) {
        let TrackSettings { level, turn_cost, brightness_cost, claimed_run_mm, max_points, .. } = self.settings;
        let res = self.res;
        while let Some(Start { p: p0, d: d0, .. }) = starts.pop() {
            if tracks.points.len() >= max_points {
                break;
            }
            if tracks.index.near(p0, None) {
                continue; // already tracked
            }
            tracks.count += 1;
            let track = tracks.count;
            let (mut p, mut d) = (p0, d0);
            let mut len = 0.0;
            let mut on_claimed: Vec<DVec3> = Vec::new();
            // Each view's brightness along the track so far, and a buffer for a direction's.
            let mut seen = vec![0.0; res.views.len()];
            res.look_ahead(p0, d0, AHEAD_MM, &mut seen);
            let mut ahead = vec![0.0; res.views.len()];
            while len < MAX_TRACK_MM && tracks.points.len() < max_points {
                let mut best: Option<(f64, DVec3)> = None;
                for &c in self.dirs.iter().filter(|&&c| c.dot(d) >= self.cos_cone) {
                    let mut score = res.look_ahead(p, c, AHEAD_MM, &mut ahead);
                    if brightness_cost > 0.0 {
                        let change: f64 =
                            ahead.iter().zip(&seen).map(|(a, b)| (a.max(0.1) / b.max(0.1)).ln().abs()).sum();
                        score -= brightness_cost * change;
                    }
                    if turn_cost > 0.0 {
                        score -= turn_cost * res.turn(p, d, c);
                    }
                    if best.is_none_or(|(s, _)| score >= s) {
                        best = Some((score, c));
                    }
                }
                let Some((_, c)) = best.filter(|b| b.0 >= level) else { break };
                res.look_ahead(p, c, STEP_MM, &mut ahead);
                for (m, r) in seen.iter_mut().zip(&ahead) {
                    *m = 0.7 * *m + 0.3 * r;
                }
                p += c * STEP_MM;
                d = (d + c).normalize();
                len += STEP_MM;
                let back_at_prior = len > 2.0 && prior_dist(p) <= 0.0;
                let joined = len > 1.0 && tracks.index.near(p, Some(track));
                if back_at_prior || joined || self.grid.index_at(p).is_none() {
                    break;
                }
                let rays = || res.views.iter().enumerate().filter_map(|(vi, v)| pixel_of(v, p).map(|px| (vi, px)));
                // A claim at another depth holds, unless its point fills at two times and this one at once.
                let takes = || self.fills_at_once.is_some_and(|fills| fills(p));
                let claimed_elsewhere = claimed_run_mm > 0.0
                    && rays().any(|r| {
                        tracks.claims.get(&r).is_some_and(|c| {
                            c.track != track
                                && c.point.distance(p) > CLAIM_TOLERANCE_MM
                                && (c.fills_at_once || !takes())
                        })
                    });
                if claimed_elsewhere {
                    on_claimed.push(p);
                    if on_claimed.len() as f64 * STEP_MM > claimed_run_mm {
                        break;
                    }
                    continue;
                }
                for q in on_claimed.drain(..).chain(std::iter::once(p)) {
                    let claim =
                        Claim { point: q, track, fills_at_once: self.fills_at_once.is_none_or(|fills| fills(q)) };
                    for (vi, v) in res.views.iter().enumerate() {
                        if let Some(px) = pixel_of(v, q) {
                            tracks.claims.entry((vi, px)).or_insert(claim);
                        }
                    }
                    tracks.index.insert(q, track);
                    tracks.points.push(q);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::masks::{Mask, above, prior_solid};
    use crate::data::projector::project_volume;
    use crate::data::volume::Grid;
    use crate::data::volume::rasterize::rasterize_segments;
    use crate::method::init::back_project;
    use crate::method::init::tests::{prior_and_images, scene, segment, to_segment};

    const PRIOR: ([f64; 3], [f64; 3]) = ([-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]);
    /// Leaves the prior (radius 1.2 mm along x) upwards and sideways.
    const VESSEL: ([f64; 3], [f64; 3]) = ([2.0, 0.0, 0.5], [6.0, 4.0, 11.0]);
    /// Floats free of the prior, 6 mm and more from the vessel; view 0 (looking along y) sees
    /// it cross the vessel at z = 5.75 mm, where a ghost (on the vessel's rays in view 1 and on
    /// this vessel's in view 0) crosses the vessel in space.
    const FLOATING: ([f64; 3], [f64; 3]) = ([0.0, -6.0, 9.0], [8.0, -6.0, 2.5]);

    /// Branches off the vessel half-way along it and never touches the prior.
    const BRANCH: ([f64; 3], [f64; 3]) = ([4.0, 2.0, 5.75], [-4.0, 7.0, 12.0]);

    /// The tracks from the prior in two views whose residuals show `missing` (radius 0.6 mm).
    fn tracks(missing: &[([f64; 3], [f64; 3])]) -> Vec<DVec3> {
        tracks_in_rounds(missing, 1)
    }

    /// [`tracks`] in `rounds` rounds.
    fn tracks_in_rounds(missing: &[([f64; 3], [f64; 3])], rounds: usize) -> Vec<DVec3> {
        tracks_checked(missing, rounds, None)
    }

    /// [`tracks_in_rounds`] with the arrival check `fills_at_once`.
    fn tracks_checked(
        missing: &[([f64; 3], [f64; 3])],
        rounds: usize,
        fills_at_once: Option<FillsAtOnce>,
    ) -> Vec<DVec3> {
        let (_, views, _, bounds) = scene();
        let views = &views[..2];
        let (prior, _) = prior_and_images(PRIOR, &[], views, &bounds);
        let grid = Grid::covering(&bounds, 0.4).unwrap();
        let segments: Vec<_> = missing.iter().map(|m| segment(m.0, m.1, 0.6)).collect();
        let residuals: Vec<Image> = project_volume(&rasterize_segments(&segments, grid, 2), views)
            .into_iter()
            .map(|data| Image { width: 64, height: 64, data })
            .collect();
        let levels = vec![0.3; 2];
        let masks: Vec<Mask> = residuals.iter().map(|r| above(r, 0.3).dilated(1)).collect();
        let solid = prior_solid(&prior, grid);
        let candidates = back_project(&grid, views, &masks, None, &residuals, Some(&solid), true);
        let res = Residuals { views, images: &residuals, levels: &levels };
        let settings = TrackSettings {
            start_mm: 1.0,
            level: 0.3,
            turn_cost: 1.0,
            brightness_cost: 1.0,
            claimed_run_mm: 1.0,
            max_points: 10_000,
            rounds,
        };
        track_from_prior(&res, &candidates, &solid, settings, fills_at_once)
    }

    /// Points farther than 1 mm from the vessel's axis, where it has left the prior (beyond
    /// 2.5 mm of the prior's axis: the junction's blob is wider).
    fn off_vessel(points: &[DVec3]) -> usize {
        points.iter().filter(|p| p.y.hypot(p.z) > 2.5 && to_segment(**p, VESSEL.0, VESSEL.1) > 1.0).count()
    }

    /// Share of the vessel's axis beyond 2 mm from the prior's axis within 1 mm of a point.
    fn covered(points: &[DVec3]) -> f64 {
        covered_of(points, VESSEL)
    }

    /// Share of `vessel`'s axis beyond 2 mm from the prior's axis within 1 mm of a point.
    fn covered_of(points: &[DVec3], vessel: ([f64; 3], [f64; 3])) -> f64 {
        let (a, b) = (DVec3::from(vessel.0), DVec3::from(vessel.1));
        let axis: Vec<DVec3> =
            (0..=100).map(|k| a.lerp(b, k as f64 / 100.0)).filter(|p| p.y.hypot(p.z) > 2.0).collect();
        axis.iter().filter(|q| points.iter().any(|p| p.distance(**q) < 1.0)).count() as f64 / axis.len() as f64
    }

    #[test]
    fn a_track_follows_the_vessel_that_leaves_the_prior() {
        let points = tracks(&[VESSEL]);
        let off = off_vessel(&points);
        eprintln!("{} points, {off} off the vessel, {:.0} % of it covered", points.len(), 100.0 * covered(&points));
        assert_eq!(off, 0, "every point within 1 mm of the vessel's axis");
        assert!(covered(&points) > 0.8, "covers the vessel: {:.2}", covered(&points));
    }

    /// With a second vessel that floats free of the prior, the two views' residuals cross in
    /// ghosts; tracked from the prior, the seeds stay on the vessel that joins it.
    #[test]
    fn a_vessel_floating_free_of_the_prior_and_its_ghosts_get_no_track() {
        let points = tracks(&[VESSEL, FLOATING]);
        let off = off_vessel(&points);
        eprintln!("{} points, {off} off the vessel, {:.0} % of it covered", points.len(), 100.0 * covered(&points));
        assert!(off * 10 <= points.len(), "at most a tenth off the vessel: {off} of {}", points.len());
        assert!(covered(&points) > 0.7, "covers the vessel: {:.2}", covered(&points));
    }

    /// A branch of a new vessel never touches the prior: the first round leaves it, the second
    /// starts beside the first round's track and follows it. (With two views a ghost leaves
    /// the junction too, on the vessel in one view and on the branch in the other.)
    #[test]
    fn a_second_round_follows_the_branch_of_a_tracked_vessel() {
        let (one, two) = (tracks_in_rounds(&[VESSEL, BRANCH], 1), tracks_in_rounds(&[VESSEL, BRANCH], 2));
        let off = |p: &[DVec3]| {
            let far = |q: &&DVec3| to_segment(**q, VESSEL.0, VESSEL.1).min(to_segment(**q, BRANCH.0, BRANCH.1)) > 1.0;
            p.iter().filter(|q| q.y.hypot(q.z) > 2.5).filter(far).count()
        };
        let (branch_one, branch_two) = (covered_of(&one, BRANCH), covered_of(&two, BRANCH));
        eprintln!(
            "branch covered: one round {branch_one:.2}, two {branch_two:.2}; off: {} of {}",
            off(&two),
            two.len()
        );
        assert!(branch_one < 0.3, "one round leaves the branch: {branch_one:.2}");
        assert!(branch_two > 0.5, "two rounds follow it: {branch_two:.2}");
        assert!(covered(&two) >= covered(&one), "and keep the vessel");
        assert!(off(&two) * 4 <= two.len(), "at most a quarter off both: {} of {}", off(&two), two.len());
    }

    /// `init.arrival_track_claims`: the vessel and its mirror image across the plane y = 0 leave
    /// the prior together and project onto the same pixels in view 0 (looking along y), at
    /// other depths: the one tracked second stops on the first one's claims. Where the first
    /// one's points fill at two times and the second's at once, the claims give way and the
    /// second is tracked on; where both fill at once they hold, as without the check.
    #[test]
    fn a_claim_whose_point_fills_at_two_times_gives_way() {
        const MIRROR: ([f64; 3], [f64; 3]) = ([2.0, 0.0, 0.5], [6.0, -4.0, 11.0]);
        let missing = [VESSEL, MIRROR];
        let unchecked = tracks_checked(&missing, 1, None);
        let (vessel, mirror) = (covered_of(&unchecked, VESSEL), covered_of(&unchecked, MIRROR));
        let (first, second) = if vessel >= mirror { (VESSEL, MIRROR) } else { (MIRROR, VESSEL) };
        let on_second = |p: DVec3| to_segment(p, second.0, second.1) < 1.0;
        let freed = tracks_checked(&missing, 1, Some(&on_second));
        let everywhere = |_: DVec3| true;
        let held = tracks_checked(&missing, 1, Some(&everywhere));
        let (before, after) = (covered_of(&unchecked, second), covered_of(&freed, second));
        eprintln!("covered: first {:.2}, second {before:.2}, freed {after:.2}", covered_of(&unchecked, first));
        assert!(covered_of(&unchecked, first) > 0.8, "the first is tracked");
        assert!(before < 0.5, "the second stops on the first one's claims: {before:.2}");
        assert!(after > before + 0.3, "and goes on where they give way: {before:.2} -> {after:.2}");
        assert!(covered_of(&freed, first) > 0.8, "the first keeps its track");
        assert_eq!(held, unchecked, "claims whose points fill at once hold");
    }

    #[test]
    fn sphere_directions_are_unit_and_cover_the_sphere() {
        let dirs = sphere_directions(DIRECTIONS);
        assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-12));
        // Every direction has a lattice direction within 10°.
        for probe in [DVec3::X, DVec3::NEG_Z, DVec3::new(1.0, -2.0, 0.5).normalize()] {
            let best = dirs.iter().map(|d| d.dot(probe)).fold(f64::MIN, f64::max);
            assert!(best > 10f64.to_radians().cos(), "{probe}: {best}");
        }
    }

    #[test]
    fn bilinear_interpolates_between_pixel_centres_and_is_zero_off_the_image() {
        let img = Image { width: 2, height: 2, data: vec![0.0, 1.0, 2.0, 3.0] };
        assert!((bilinear(&img, 0.5, 0.5) - 1.5).abs() < 1e-12);
        assert!((bilinear(&img, 1.0, 0.0) - 1.0).abs() < 1e-12);
        assert_eq!(bilinear(&img, -5.0, 0.0), 0.0);
    }
}
