//! Initial Gaussians from what a user has — the DSA images, their geometry and the prior mesh:
//!
//! - N1: centres sampled area-uniformly on the prior surface;
//! - N2: the residual back-projection. Per view, vessel mask minus the dilated projection of the
//!   (solid) prior; each voxel of a back-projection grid is looked up in every view's residual
//!   and kept when supported in all views (intersection) and outside the prior; the N2 voxels
//!   with the largest geometric-mean residual intensity become centres (jittered inside the voxel).
//!   With `init.subtract_prior` the prior's projection is subtracted instead of masked: each
//!   view's image minus the prior mesh's chord lengths at a fitted contrast per mm, so a vessel
//!   behind the prior in one view still shows there.
//!   Variants: union instead of intersection, uniform random, masks instead of residuals, and
//!   (`init.grow_claims_mm`) the supported voxels grown from the prior one depth per pixel
//!   (`crate::method::seed_growth`).
//! - with `init.track_max_views`, the points of the vessels tracked from the prior through both
//!   views' residuals besides (`crate::method::tracking`).
//! - with two views and the case's arrival maps (`init.arrival_seeds`,
//!   `init.arrival_track_starts`), the image seeds and the tracks' starts only where both views
//!   fill at once (`crate::method::arrival`: the ghosts where two vessels cross fill at two times).
//! - isotropic scales from the mean squared distance to the k nearest other centres, identity
//!   rotations.

use std::borrow::Cow;

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::config::{InitConfig, SeedMode};
use crate::data::case::images::Image;
use crate::data::masks::{
    Mask, above, contrast_per_mm, max_filtered, minus_solid, pixel_of, prior_solid, silhouettes, vessel_level,
};
use crate::data::mesh::TriMesh;
use crate::data::mesh::sample::sample_surface;
use crate::data::projector::matched::{BLUR_SIGMAS_PX, OFFSETS_MM, fit_mesh_projection};
use crate::data::projector::mesh::mesh_chords;
use crate::data::volume::{BoxMm, Grid, Volume};
use crate::error::{CoreError, Result};
use crate::method::arrival::arrives_together;
use crate::method::model::{GaussianInit, ScaleBounds};
use crate::method::seed_growth::grow_from;
use crate::method::tracking::{FillsAtOnce, Residuals, TrackSettings, track_from_prior};

/// A supported voxel of the back-projection: its score, its centre (mm) and whether every view
/// that sees it shows residual there (no view passed it only because the prior hides it).
pub(crate) type Scored = (f64, DVec3, bool);

/// Seeds scored by the back-projection of per-view support masks and intensity images.
pub(crate) fn back_project(
    grid: &Grid,
    views: &[ConeBeamView],
    masks: &[Mask],
    occluded: Option<&[Mask]>,
    values: &[Image],
    prior: Option<&Volume<u8>>,
    intersect: bool,
) -> Vec<Scored> {
    // With occlusion masks, a view where the prior hides the pixel supports without residual,
    // but at least half of the views (rounded up) must see residual.
    let min_residual = if occluded.is_some() { views.len().div_ceil(2) } else { views.len() };
    let [nx, ny, nz] = grid.dims;
    (0..nx)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut out = Vec::new();
            for j in 0..ny {
                for k in 0..nz {
                    let idx = grid.index(i, j, k);
                    if prior.is_some_and(|p| p.data[idx] != 0) {
                        continue;
                    }
                    let c = grid.centre_mm(i, j, k);
                    let (mut supported, mut residual, mut seen) = (0usize, 0usize, 0usize);
                    let mut log_sum = 0.0;
                    let mut sum = 0.0;
                    for (vi, ((v, m), img)) in views.iter().zip(masks).zip(values).enumerate() {
                        let Some(px) = pixel_of(v, c) else { continue };
                        seen += 1;
                        let hidden = occluded.is_some_and(|o| o[vi].data[px]);
                        if m.data[px] || hidden {
                            supported += 1;
                        }
                        // Scored by the views that show residual (an occluded view's pixel is
                        // bright from the prior in front of or behind it).
                        if m.data[px] {
                            residual += 1;
                            let val = (img.data[px] as f64).max(1e-12);
                            log_sum += val.ln();
                            sum += val;
                        }
                    }
                    let keep =
                        if intersect { supported == views.len() && residual >= min_residual } else { supported > 0 };
                    if keep {
                        let score = if intersect { (log_sum / residual.max(1) as f64).exp() } else { sum };
                        out.push((score, c, residual == seen));
                    }
                }
            }
            out
        })
        .collect()
}

/// The N2 centres for `mode`.
#[allow(clippy::too_many_arguments)]
pub fn n2_seeds(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    images: &[Image],
    prior: Option<&TriMesh>,
    bounds: &BoxMm,
    voxel_mm: f64,
    seed: u64,
    arrival: Option<&[Image]>,
) -> Result<Vec<DVec3>> {
    let n2 = cfg.n2_for(views.len());
    // With `n2 = 0` the tracked seeds alone (the prior-only member's, `run.member_tracks_max_views`).
    let tracking = views.len() <= cfg.track_max_views;
    if (n2 == 0 && !tracking) || cfg.n2_mode == SeedMode::None {
        return Ok(Vec::new());
    }
    let h = if cfg.n2_voxel_mm > 0.0 { cfg.n2_voxel_mm } else { voxel_mm };
    let grid = Grid::covering(bounds, h)?;
    let solid = prior.map(|p| prior_solid(p, grid));
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4e32);
    if cfg.n2_mode == SeedMode::Uniform {
        let mut out = Vec::with_capacity(n2);
        let mut tries = 0usize;
        while out.len() < n2 && tries < 1000 * n2 {
            tries += 1;
            let p = DVec3::new(
                rng.random_range(bounds.min_mm[0]..bounds.max_mm[0]),
                rng.random_range(bounds.min_mm[1]..bounds.max_mm[1]),
                rng.random_range(bounds.min_mm[2]..bounds.max_mm[2]),
            );
            let inside_prior = solid.as_ref().is_some_and(|s| {
                let ijk = [0, 1, 2].map(|a| ((p[a] - grid.origin_mm[a]) / h).floor() as usize);
                ijk.iter().zip(grid.dims).all(|(&i, d)| i < d) && s.get(ijk[0], ijk[1], ijk[2]) != 0
            });
            if !inside_prior {
                out.push(p);
            }
        }
        return Ok(out);
    }
    let levels: Vec<f64> = images.iter().map(|img| vessel_level(img, cfg.mask_threshold)).collect();
    let masks: Vec<Mask> = images.iter().zip(&levels).map(|(img, &level)| above(img, level)).collect();
    let intersect = cfg.n2_mode != SeedMode::ResidualUnion;
    let exclude = if cfg.n2_mode == SeedMode::AllViewsIntersect { None } else { solid.as_ref() };
    let shown = ResidualViews {
        cfg,
        views,
        images,
        prior,
        solid: solid.as_ref(),
        masks: &masks,
        levels: &levels,
        grid: &grid,
        exclude,
        intersect,
    };
    let seeds_removal = PriorRemoval { fit: cfg.fit_prior_projection, dilation_px: cfg.prior_dilation_px };
    // The image seeds' residual; none without image seeds (the tracked seeds alone).
    let seeding = if n2 > 0 { Some(shown.residual(seeds_removal)?) } else { None };
    // Tracked from the prior (before the growth or the connectivity filter thins the starts).
    let tracked = match exclude {
        Some(s) if intersect && tracking => {
            let track_removal = PriorRemoval {
                fit: cfg.track_fit_prior_projection.unwrap_or(seeds_removal.fit),
                dilation_px: cfg.track_prior_dilation_px.unwrap_or(seeds_removal.dilation_px),
            };
            // The tracker reads the image seeds' residual unless it removes the prior its own way.
            let own;
            let read = match &seeding {
                Some(r) if track_removal == seeds_removal => r,
                _ => {
                    own = shown.residual(track_removal)?;
                    &own
                }
            };
            let res = Residuals { views, images: &read.values, levels: &levels };
            // With `init.arrival_track_starts`, tracks start only where both views fill at once;
            // with `init.arrival_track_claims`, a claim whose point fills at two times gives way
            // to a point that fills at once, and the tracks, going farther, get their own rounds.
            let maps = arrival_pair(cfg, views, arrival);
            let together = maps.filter(|_| cfg.arrival_track_claims).map(|maps| fills_at_once(cfg, views, maps));
            let claims_checked = together.is_some();
            let settings = TrackSettings {
                start_mm: cfg.track_start_mm,
                level: cfg.track_level,
                turn_cost: cfg.track_turn_cost,
                brightness_cost: cfg.track_brightness_cost,
                claimed_run_mm: cfg.track_claimed_run_mm,
                max_points: cfg.track_max_points_for(claims_checked),
                rounds: cfg.track_rounds_for(claims_checked),
            };
            let starts: Cow<'_, [Scored]> = match maps {
                Some(maps) if cfg.arrival_track_starts => {
                    Cow::Owned(arriving(cfg, views, maps, read.scored.par_iter().copied()))
                }
                _ => Cow::Borrowed(&read.scored),
            };
            track_from_prior(&res, &starts, s, settings, together.as_ref().map(|f| f as FillsAtOnce))
        }
        _ => Vec::new(),
    };
    let Some(Residual { support, occluded, mut scored, .. }) = seeding else {
        return Ok(tracked);
    };
    if let Some(maps) = arrival_pair(cfg, views, arrival).filter(|_| cfg.arrival_seeds) {
        scored = arriving(cfg, views, maps, scored);
    }
    // Not for the mask-only mode, which ignores the prior by design.
    let (mut spacing_mm, mut n) = (cfg.seed_spacing_mm_for(views.len()), n2);
    if let Some(s) = exclude {
        let to_prior = cfg.connected_to_prior_mm > 0.0 && views.len() <= cfg.connected_max_views;
        if to_prior && cfg.grow_claims_mm > 0.0 {
            scored = grow_from(&grid, views, &support, scored, s, cfg.connected_to_prior_mm, cfg.grow_claims_mm);
            (spacing_mm, n) = (cfg.grow_claims_spacing_mm, cfg.grow_claims_n2);
        } else if to_prior {
            scored = connected_to_anchors(scored, s, cfg.connected_to_prior_mm, |_| false);
        } else if occluded.is_some() && cfg.occluded_connected {
            // A voxel that a view passed only because the prior hides it must belong to a group
            // that holds a voxel every view supports with residual, or that reaches the prior.
            scored = connected_to_anchors(scored, s, cfg.connected_to_prior_mm, |&(_, _, full)| full);
        }
    }
    let mut centres = best_centres(scored, spacing_mm, n, h, &mut rng);
    centres.extend(tracked);
    Ok(centres)
}

/// The `candidates` whose points fill at once in both `views` ([`arrives_together`] with the
/// two views' arrival `maps`, within `init.arrival_tolerance_frames`).
pub(crate) fn arriving(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    maps: &[Image],
    candidates: impl IntoParallelIterator<Item = Scored>,
) -> Vec<Scored> {
    let together = fills_at_once(cfg, views, maps);
    candidates.into_par_iter().filter(|(_, c, _)| together(*c)).collect()
}

/// Whether a point fills at once in both `views` ([`arrives_together`] with the two views'
/// arrival `maps`, within `init.arrival_tolerance_frames`, the prior's exit window
/// `init.arrival_prior_exit_px`).
fn fills_at_once<'a>(
    cfg: &InitConfig,
    views: &'a [ConeBeamView],
    maps: &'a [Image],
) -> impl Fn(DVec3) -> bool + Sync + 'a {
    let tolerance = cfg.arrival_tolerance_frames as f32;
    // Maps without the prior hidden (`arrival_prior_unknown` off) never open the window.
    let exit = cfg.arrival_prior_exit_px;
    move |p| arrives_together(views, maps, p, tolerance, exit)
}

/// The two views' arrival maps, where a run of two views has them and checks seeds with them
/// (`init.arrival_seeds`, `init.arrival_track_starts`, `init.arrival_reseeds`).
pub(crate) fn arrival_pair<'m>(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    arrival: Option<&'m [Image]>,
) -> Option<&'m [Image]> {
    arrival.filter(|m| cfg.checks_arrival() && views.len() == 2 && m.len() == 2)
}

/// How each view's image is rid of the prior before the back-projection
/// (`init.fit_prior_projection`, `init.prior_dilation_px`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct PriorRemoval {
    fit: bool,
    dilation_px: u32,
}

/// What the views show beside the prior: per view the support mask and the image that scores the
/// voxels, (`init.occluded_views_support`, intersect modes) the masks where the prior hides a
/// vessel, and the back-projection's supported voxels.
struct Residual<'a> {
    support: Vec<Mask>,
    values: Cow<'a, [Image]>,
    occluded: Option<Vec<Mask>>,
    scored: Vec<Scored>,
}

/// The inputs from which [`Residual`]s are taken (one per [`PriorRemoval`]).
struct ResidualViews<'a> {
    cfg: &'a InitConfig,
    views: &'a [ConeBeamView],
    images: &'a [Image],
    prior: Option<&'a TriMesh>,
    /// The prior's solid on the back-projection grid.
    solid: Option<&'a Volume<u8>>,
    /// Each view's vessel mask and vessel level (contrast × mm).
    masks: &'a [Mask],
    levels: &'a [f64],
    /// The back-projection's grid, the solid its voxels must lie outside, and whether every view
    /// must support a voxel.
    grid: &'a Grid,
    exclude: Option<&'a Volume<u8>>,
    intersect: bool,
}

impl<'a> ResidualViews<'a> {
    /// The residual with the prior removed as `removal` says, back-projected.
    fn residual(&self, removal: PriorRemoval) -> Result<Residual<'a>> {
        let mut r = self.shown(removal)?;
        r.occluded = r.occluded.filter(|_| self.intersect);
        r.scored = back_project(
            self.grid,
            self.views,
            &r.support,
            r.occluded.as_deref(),
            &r.values,
            self.exclude,
            self.intersect,
        );
        Ok(r)
    }

    /// The residual before its back-projection (`scored` empty).
    fn shown(&self, removal: PriorRemoval) -> Result<Residual<'a>> {
        let (cfg, views, images) = (self.cfg, self.views, self.images);
        let mut values: Cow<'a, [Image]> = Cow::Borrowed(images);
        if cfg.n2_mode == SeedMode::AllViewsIntersect {
            let support = self.masks.iter().map(|m| m.dilated(cfg.residual_dilation_px)).collect();
            return Ok(Residual { support, values, occluded: None, scored: Vec::new() });
        }
        let Some(s) = self.solid else {
            return Err(CoreError::invalid(format!("init.n2_mode {:?} needs a prior mesh", cfg.n2_mode)));
        };
        let subtracted = self.prior.filter(|_| cfg.subtract_prior);
        let occluded_support = cfg.occluded_views_support && views.len() >= cfg.occluded_min_views;
        // The prior's dilated silhouettes, where something reads them.
        let prior_sil: Vec<Mask> = if subtracted.is_none() || occluded_support {
            silhouettes(s, views).iter().map(|p| p.dilated(removal.dilation_px)).collect()
        } else {
            Vec::new()
        };
        let occluded = occluded_support.then(|| {
            self.masks.iter().zip(&prior_sil).map(|(m, p)| m.dilated(cfg.residual_dilation_px).and(p)).collect()
        });
        let mut support = Vec::with_capacity(views.len());
        for (vi, m) in self.masks.iter().enumerate() {
            let shown = match subtracted {
                // The prior's projection subtracted instead of masked: a pixel shows residual
                // where the image exceeds the prior's chord (the longest within the dilation:
                // the grey-level analogue of dilating its silhouette) at the fitted contrast per
                // mm, and what is left scores the voxels.
                Some(mesh) => {
                    let (chords, contrast) = if removal.fit {
                        let fit = fit_mesh_projection(&images[vi], mesh, &views[vi], &OFFSETS_MM, &BLUR_SIGMAS_PX)?;
                        (fit.chords, fit.contrast_per_mm)
                    } else {
                        let sharp = mesh_chords(mesh, &views[vi])?;
                        let contrast = contrast_per_mm(&images[vi], &sharp);
                        (sharp, contrast)
                    };
                    let longest = max_filtered(&chords, m.width as usize, removal.dilation_px);
                    let rest = minus_solid(&images[vi], &longest, contrast);
                    let shown = above(&rest, self.levels[vi]);
                    values.to_mut()[vi] = rest;
                    shown
                }
                None => m.minus(&prior_sil[vi]),
            };
            support.push(shown.dilated(cfg.residual_dilation_px));
        }
        Ok(Residual { support, values, occluded, scored: Vec::new() })
    }
}

/// The centres (mm) of the `n` best-scored voxels (of side `voxel_mm`), at least `spacing_mm`
/// apart when it is > 0 ([`spread`]), each jittered uniformly inside its voxel.
pub(crate) fn best_centres(
    mut scored: Vec<Scored>,
    spacing_mm: f64,
    n: usize,
    voxel_mm: f64,
    rng: &mut ChaCha8Rng,
) -> Vec<DVec3> {
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    if spacing_mm > 0.0 {
        scored = spread(scored, spacing_mm, n);
    }
    scored.truncate(n);
    scored
        .into_iter()
        .map(|(_, c, _)| {
            c + DVec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5))
                * voxel_mm
        })
        .collect()
}

/// Isotropic Gaussians with identity rotations at `centres` (mm), scales (mm) clamped to `bounds`.
pub(crate) fn isotropic_gaussians(centres: &[DVec3], scales: &[f64], bounds: ScaleBounds) -> GaussianInit {
    let mut g = GaussianInit::default();
    for (c, &s) in centres.iter().zip(scales) {
        g.means.extend([c.x as f32, c.y as f32, c.z as f32]);
        g.raw_scales.extend([bounds.inverse((s as f32).clamp(bounds.min_mm, bounds.max_mm)); 3]);
        g.rotations.extend([1.0, 0.0, 0.0, 0.0]);
    }
    g
}

/// The first `n` of `sorted` (best first) that lie at least `spacing_mm` from every one taken
/// before them (greedy non-maximum suppression on a hashed grid of `spacing_mm` cells).
pub(crate) fn spread(sorted: Vec<Scored>, spacing_mm: f64, n: usize) -> Vec<Scored> {
    let cell = |p: DVec3| (p / spacing_mm).floor().as_ivec3();
    let mut taken: std::collections::HashMap<glam::IVec3, Vec<DVec3>> = std::collections::HashMap::new();
    let mut out = Vec::with_capacity(n.min(sorted.len()));
    for s in sorted {
        if out.len() == n {
            break;
        }
        let c = cell(s.1);
        let near = (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    taken
                        .get(&(c + glam::IVec3::new(dx, dy, dz)))
                        .is_some_and(|ps| ps.iter().any(|q| q.distance_squared(s.1) < spacing_mm * spacing_mm))
                })
            })
        });
        if !near {
            taken.entry(c).or_default().push(s.1);
            out.push(s);
        }
    }
    out
}

/// The scored voxels (centres on `prior`'s grid) whose 26-connected group of scored voxels holds
/// an anchor or comes within `reach_mm` of the prior solid (`reach_mm` = 0: anchors only).
pub(crate) fn connected_to_anchors(
    scored: Vec<Scored>,
    prior: &Volume<u8>,
    reach_mm: f64,
    is_anchor: impl Fn(&Scored) -> bool,
) -> Vec<Scored> {
    let grid = prior.grid;
    let index_of = |c: DVec3| grid.index_at(c);
    // Distance² (mm²) of every voxel outside the prior to the prior.
    let outside = prior.map(|v| u8::from(v == 0));
    let dist2 = crate::data::volume::edt::squared_edt(&outside);
    let mut supported = vec![false; grid.len()];
    let mut reached = vec![false; grid.len()];
    let mut stack = Vec::new();
    for s in &scored {
        if let Some(i) = index_of(s.1) {
            supported[i] = true;
            if !reached[i] && (is_anchor(s) || (reach_mm > 0.0 && dist2[i] <= reach_mm * reach_mm)) {
                reached[i] = true;
                stack.push(i);
            }
        }
    }
    // Flood fill from the anchors and the supported voxels within reach of the prior.
    grid.flood_fill_26(&mut reached, stack, |j| supported[j]);
    scored.into_iter().filter(|s| index_of(s.1).is_some_and(|i| reached[i])).collect()
}

/// Isotropic scale (mm) of each point: sqrt of the mean squared distance to its `k` nearest
/// other points (a point alone gets `fallback`).
pub fn knn_scales(points: &[DVec3], k: usize, fallback: f64) -> Vec<f64> {
    if points.len() < 2 {
        return vec![fallback; points.len()];
    }
    let pts: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts).expect("finite points");
    let kk = (k + 1).min(points.len());
    let n = std::num::NonZero::new(kk).expect("k + 1 ≥ 1");
    tree.query_batch(&pts)
        .nearest_n::<SquaredEuclidean<f64>>(n)
        .execute()
        .into_iter()
        .map(|res| {
            let d: Vec<f64> = res.iter().skip(1).map(|r| r.distance).collect();
            if d.is_empty() { fallback } else { (d.iter().sum::<f64>() / d.len() as f64).sqrt() }
        })
        .collect()
}

/// The initial Gaussians and what went into them.
#[derive(Debug, Clone)]
pub struct Initialisation {
    pub gaussians: GaussianInit,
    /// How many came from the prior (first) and from the images (after).
    pub n1: usize,
    pub n2: usize,
}

/// N1 + N2 centres with kNN isotropic scales and identity rotations.
#[allow(clippy::too_many_arguments)]
pub fn initialise(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    images: &[Image],
    prior: Option<&TriMesh>,
    bounds: &BoxMm,
    voxel_mm: f64,
    scale_bounds: ScaleBounds,
    seed: u64,
    arrival: Option<&[Image]>,
) -> Result<Initialisation> {
    let mut centres: Vec<DVec3> = Vec::new();
    let use_prior = cfg.n2_mode != SeedMode::AllViewsIntersect;
    if cfg.n1 > 0 && use_prior {
        let p = prior.ok_or_else(|| CoreError::invalid("init.n1 > 0 needs a prior mesh (or set init.n1 = 0)"))?;
        centres.extend(sample_surface(p, cfg.n1, seed));
    }
    let n1 = centres.len();
    centres.extend(n2_seeds(cfg, views, images, prior.filter(|_| use_prior), bounds, voxel_mm, seed, arrival)?);
    let n2 = centres.len() - n1;
    if centres.is_empty() {
        return Err(CoreError::invalid("initialisation produced no Gaussian (empty prior and no image support)"));
    }
    let scales = knn_scales(&centres, cfg.knn, voxel_mm);
    Ok(Initialisation { gaussians: isotropic_gaussians(&centres, &scales, scale_bounds), n1, n2 })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::data::mesh::marching::extract_isosurface;
    use crate::data::projector::project_volume;
    use crate::data::tree::Segment;
    use crate::data::volume::rasterize::rasterize_segments;
    use ctadsa_render::TigreGeometry;

    pub(crate) fn segment(a: [f64; 3], b: [f64; 3], r: f64) -> Segment {
        Segment { child: 0, start_mm: DVec3::from(a), end_mm: DVec3::from(b), start_radius_mm: r, end_radius_mm: r }
    }

    /// Distance (mm) from `p` to the segment `a`–`b`.
    pub(crate) fn to_segment(p: DVec3, a: [f64; 3], b: [f64; 3]) -> f64 {
        let (a, b) = (DVec3::from(a), DVec3::from(b));
        let t = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
        (a + t * (b - a) - p).length()
    }

    const PRIOR: ([f64; 3], [f64; 3]) = ([-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]);
    const MISSING: ([f64; 3], [f64; 3]) = ([4.0, 5.0, -8.0], [4.0, 5.0, 8.0]);

    /// A thick vessel the prior has and a thin one it misses, seen in three views; the prior
    /// mesh, the views and their images.
    pub(crate) fn scene() -> (TriMesh, Vec<ConeBeamView>, Vec<Image>, BoxMm) {
        let bounds = BoxMm { min_mm: [-15.0; 3], max_mm: [15.0; 3] };
        let views: Vec<ConeBeamView> = [-90.0, 0.0, -45.0]
            .iter()
            .map(|&primary_deg| {
                ConeBeamView::from_tigre(&TigreGeometry {
                    dsd_mm: 700.0,
                    dso_mm: 500.0,
                    detector_px: [64, 64],
                    pixel_mm: [0.75, 0.75],
                    offset_mm: [0.0, 0.0],
                    primary_deg,
                    secondary_deg: 0.0,
                })
                .unwrap()
            })
            .collect();
        let (prior, images) = prior_and_images(PRIOR, &[MISSING], &views, &bounds);
        (prior, views, images, bounds)
    }

    /// The prior mesh (`prior`, radius 1.2 mm) and the views' images of it with `missing`
    /// vessels (radius 0.6 mm), on the scene's 0.4 mm grid.
    pub(crate) fn prior_and_images(
        prior: ([f64; 3], [f64; 3]),
        missing: &[([f64; 3], [f64; 3])],
        views: &[ConeBeamView],
        bounds: &BoxMm,
    ) -> (TriMesh, Vec<Image>) {
        let grid = Grid::covering(bounds, 0.4).unwrap();
        let mut segments = vec![segment(prior.0, prior.1, 1.2)];
        segments.extend(missing.iter().map(|m| segment(m.0, m.1, 0.6)));
        let complete = rasterize_segments(&segments, grid, 2);
        let mesh = extract_isosurface(&rasterize_segments(&segments[..1], grid, 2), 0.5);
        let images =
            project_volume(&complete, views).into_iter().map(|data| Image { width: 64, height: 64, data }).collect();
        (mesh, images)
    }

    #[test]
    fn residual_seeds_lie_on_the_vessel_the_prior_misses() {
        let (prior, views, images, bounds) = scene();
        // The missed vessel here floats 3.8 mm from the prior: no connectivity filter.
        let cfg = InitConfig { n2: 300, prior_dilation_px: 1, connected_to_prior_mm: 0.0, ..InitConfig::default() };
        let seeds = n2_seeds(&cfg, &views, &images, Some(&prior), &bounds, 0.4, 7, None).unwrap();
        assert!(seeds.len() >= 50, "only {} seeds", seeds.len());
        let on_missing = seeds.iter().filter(|p| to_segment(**p, MISSING.0, MISSING.1) < 1.5).count();
        let on_prior = seeds.iter().filter(|p| to_segment(**p, PRIOR.0, PRIOR.1) < 1.2).count();
        eprintln!("residual seeds: {} of {} on the missing vessel", on_missing, seeds.len());
        assert!(on_missing as f64 >= 0.8 * seeds.len() as f64, "{on_missing} of {} on the missing vessel", seeds.len());
        assert_eq!(on_prior, 0, "seeds inside the prior");
    }

    #[test]
    fn occluded_views_support_seeds_vessels_behind_the_prior_that_connect_to_it() {
        let (_, views, _, bounds) = scene();
        // A short prior vessel and two thin ones parallel to it, hidden behind it in view 0
        // (shifted along that view's rays, d = +y): one 4.5 mm away (its group comes within
        // reach of the prior), one 10 mm away (connected to nothing).
        let short = ([-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]);
        let d = -views[0].source_mm().normalize();
        let shifted = |k: f64| {
            let (a, b) = (DVec3::from(short.0) + k * d, DVec3::from(short.1) + k * d);
            (a.to_array(), b.to_array())
        };
        let (near, far) = (shifted(4.5), shifted(10.0));
        let (prior, images) = prior_and_images(short, &[near, far], &views, &bounds);
        let seeds_with = |occluded: bool, connected: bool| {
            let cfg = InitConfig {
                n2: 3000,
                prior_dilation_px: 1,
                occluded_views_support: occluded,
                occluded_connected: connected,
                ..InitConfig::default()
            };
            n2_seeds(&cfg, &views, &images, Some(&prior), &bounds, 0.4, 7, None).unwrap()
        };
        let on =
            |seeds: &[DVec3], s: ([f64; 3], [f64; 3])| seeds.iter().filter(|p| to_segment(**p, s.0, s.1) < 1.0).count();
        let off = seeds_with(false, true);
        let (with, unfiltered) = (seeds_with(true, true), seeds_with(true, false));
        eprintln!(
            "near / far hidden vessel seeds: off {} / {}, on {} / {}, on without the connection test {} / {}",
            on(&off, near),
            on(&off, far),
            on(&with, near),
            on(&with, far),
            on(&unfiltered, near),
            on(&unfiltered, far)
        );
        assert_eq!(on(&off, near) + on(&off, far), 0, "hidden in view 0: no residual support without the option");
        assert!(on(&with, near) > 10, "the vessel next to the prior is seeded");
        assert!(on(&unfiltered, far) > 10, "the far one too without the connection test");
        assert_eq!(on(&with, far), 0, "the far one connects to nothing: dropped");
        let cfg = InitConfig { n2: 3000, prior_dilation_px: 1, occluded_views_support: true, ..InitConfig::default() };
        let two = n2_seeds(&cfg, &views[..2], &images[..2], Some(&prior), &bounds, 0.4, 7, None).unwrap();
        assert_eq!(on(&two, near), 0, "not applied below occluded_min_views");
    }

    /// A model seeded by its tracks alone (no image seeds), the prior subtracted and dilated by
    /// a pixel, tracking with two views.
    fn tracks_only() -> InitConfig {
        InitConfig { n2: 0, track_max_views: 2, prior_dilation_px: 1, subtract_prior: true, ..InitConfig::default() }
    }

    /// The prior-only member's seeds (`run.member_tracks_max_views`): with `n2 = 0` and
    /// tracking on, the tracks alone, along the vessel that leaves the prior.
    #[test]
    fn with_no_seed_count_the_tracks_are_the_seeds() {
        let (_, views, _, bounds) = scene();
        let leaving = ([2.0, 0.0, 0.5], [6.0, 4.0, 11.0]);
        let (prior, images) = prior_and_images(PRIOR, &[leaving], &views[..2], &bounds);
        let cfg = tracks_only();
        let seeds = n2_seeds(&cfg, &views[..2], &images, Some(&prior), &bounds, 0.4, 7, None).unwrap();
        let on = seeds.iter().filter(|p| to_segment(**p, leaving.0, leaving.1) < 1.5).count();
        eprintln!("{on} of {} tracked seeds on the vessel", seeds.len());
        assert!(seeds.len() >= 10, "only {} seeds", seeds.len());
        assert_eq!(on, seeds.len(), "every seed on the vessel that leaves the prior");
        // The prior's projection fitted to the views and not dilated: the tracks go as far along
        // the vessel, and what the undilated projection leaves along the prior's edge is tracked
        // too, beside the prior and nowhere else.
        let fitted = InitConfig { fit_prior_projection: true, prior_dilation_px: 0, ..cfg.clone() };
        let seeds_fitted = n2_seeds(&fitted, &views[..2], &images, Some(&prior), &bounds, 0.4, 7, None).unwrap();
        let (on_vessel, off): (Vec<DVec3>, Vec<DVec3>) =
            seeds_fitted.iter().partition(|p| to_segment(**p, leaving.0, leaving.1) < 1.5);
        eprintln!("fitted: {} of {} tracked seeds on the vessel", on_vessel.len(), seeds_fitted.len());
        assert!(on_vessel.len() >= on, "{} against {on} on the vessel", on_vessel.len());
        let beside_prior = |p: &DVec3| to_segment(*p, PRIOR.0, PRIOR.1) < 2.5;
        assert!(off.iter().all(beside_prior), "off the vessel and away from the prior: {off:?}");
        let off = InitConfig { track_max_views: 0, ..cfg.clone() };
        assert!(n2_seeds(&off, &views[..2], &images, Some(&prior), &bounds, 0.4, 7, None).unwrap().is_empty());
        let (_, three_images) = prior_and_images(PRIOR, &[leaving], &views, &bounds);
        let three_views = n2_seeds(&cfg, &views, &three_images, Some(&prior), &bounds, 0.4, 7, None);
        assert!(three_views.unwrap().is_empty(), "more views than track_max_views: none");
    }

    /// `init.arrival_track_starts`: tracks start only where both views fill at once. With the
    /// scene's own arrival maps the vessel leaving the prior is tracked as without them; with one
    /// view's frames shifted (every point fills at two times) nothing is.
    #[test]
    fn tracks_start_where_both_views_fill_at_once() {
        use crate::data::synth::arrival::{ArrivalSpec, arrival_map};
        use crate::data::tree::{TreeNode, VesselTree};
        let (_, views, _, bounds) = scene();
        let views = &views[..2];
        let leaving = ([2.0, 0.0, 0.5], [6.0, 4.0, 11.0]);
        let (prior, images) = prior_and_images(PRIOR, &[leaving], views, &bounds);
        let node = |id, parent, p| TreeNode { id, kind: 0, position_mm: DVec3::from(p), radius_mm: 0.6, parent };
        let tree = VesselTree {
            nodes: vec![
                node(1, None, PRIOR.0),
                node(2, Some(0), PRIOR.1),
                node(3, None, leaving.0),
                node(4, Some(2), leaving.1),
            ],
        };
        let spec = ArrivalSpec { frames_per_s: 10.0, flow_mm_s: 50.0 };
        let maps: Vec<Image> = views.iter().map(|v| arrival_map(&tree, v, &spec)).collect();
        let mut shifted = maps.clone();
        shifted[1].data.iter_mut().filter(|f| **f >= 0.0).for_each(|f| *f += 5.0);
        let cfg = InitConfig { arrival_track_starts: true, ..tracks_only() };
        let seeds =
            |maps: Option<&[Image]>| n2_seeds(&cfg, views, &images, Some(&prior), &bounds, 0.4, 7, maps).unwrap();
        let (unchecked, agreeing, disagreeing) = (seeds(None), seeds(Some(&maps)), seeds(Some(&shifted)));
        eprintln!("tracked seeds: {} unchecked, {} with the scene's maps", unchecked.len(), agreeing.len());
        assert!(unchecked.len() >= 10, "only {} seeds", unchecked.len());
        assert!(agreeing.len() * 10 >= unchecked.len() * 9, "{} of {} tracked", agreeing.len(), unchecked.len());
        assert!(disagreeing.is_empty(), "{} tracked from points that fill at two times", disagreeing.len());
    }

    /// `init.track_fit_prior_projection` / `init.track_prior_dilation_px`: the tracks read the
    /// residual they name, the image seeds keep their own.
    #[test]
    fn the_tracker_may_remove_the_prior_its_own_way() {
        let (_, views, _, bounds) = scene();
        let leaving = ([2.0, 0.0, 0.5], [6.0, 4.0, 11.0]);
        let (prior, images) = prior_and_images(PRIOR, &[leaving], &views[..2], &bounds);
        let seeds =
            |cfg: &InitConfig| n2_seeds(cfg, &views[..2], &images, Some(&prior), &bounds, 0.4, 7, None).unwrap();
        let base = tracks_only();
        let fitted = InitConfig { fit_prior_projection: true, prior_dilation_px: 0, ..base.clone() };
        let own =
            InitConfig { track_fit_prior_projection: Some(true), track_prior_dilation_px: Some(0), ..base.clone() };
        let (tracked_fitted, tracked_own, tracked_base) = (seeds(&fitted), seeds(&own), seeds(&base));
        assert_ne!(tracked_fitted, tracked_base, "the fitted, undilated residual tracks differently here");
        assert_eq!(tracked_own, tracked_fitted, "the tracker's own settings: the tracks of the fitted residual");
        // With image seeds and no tracking, the tracker's settings change nothing.
        let image = InitConfig { n2: 300, track_max_views: 0, ..base.clone() };
        let image_own =
            InitConfig { track_fit_prior_projection: Some(true), track_prior_dilation_px: Some(0), ..image.clone() };
        assert_eq!(seeds(&image), seeds(&image_own));
        // Both: the image seeds as without the tracker's settings, then the tracks of the fitted residual.
        let both = InitConfig { n2: 300, ..own.clone() };
        let image_seeds = seeds(&image);
        let both_seeds = seeds(&both);
        assert_eq!(both_seeds[..image_seeds.len()], image_seeds[..]);
        assert_eq!(both_seeds[image_seeds.len()..], tracked_fitted[..]);
    }

    #[test]
    fn mask_intersection_seeds_both_vessels_and_the_count_is_capped() {
        let (_, views, images, bounds) = scene();
        let cfg = InitConfig { n2: 400, n2_mode: SeedMode::AllViewsIntersect, ..InitConfig::default() };
        let seeds = n2_seeds(&cfg, &views, &images, None, &bounds, 0.4, 7, None).unwrap();
        assert!(seeds.len() <= 400);
        let near = |p: &DVec3| to_segment(*p, MISSING.0, MISSING.1) < 1.5 || to_segment(*p, PRIOR.0, PRIOR.1) < 2.0;
        let good = seeds.iter().filter(|p| near(p)).count();
        assert!(good as f64 >= 0.9 * seeds.len() as f64, "{good} of {} near a vessel", seeds.len());
        assert!(seeds.iter().any(|p| to_segment(*p, PRIOR.0, PRIOR.1) < 2.0), "the prior vessel is seeded too");
    }

    #[test]
    fn two_view_runs_seed_their_own_count() {
        let (_, views, images, bounds) = scene();
        let cfg = InitConfig {
            n2: 400,
            n2_two_views: Some(50),
            n2_mode: SeedMode::AllViewsIntersect,
            ..InitConfig::default()
        };
        let three = n2_seeds(&cfg, &views, &images, None, &bounds, 0.4, 7, None).unwrap();
        let two = n2_seeds(&cfg, &views[..2], &images[..2], None, &bounds, 0.4, 7, None).unwrap();
        assert!(views.len() >= 3 && three.len() > 50, "{} seeds with {} views", three.len(), views.len());
        assert_eq!(two.len(), 50);
    }

    /// Two vertical vessels filled in opposite directions, A from z = −12 mm up and B from
    /// z = +12 mm down, seen in two views: their back-projections cross in two ghosts, which pair
    /// A's image in one view with B's in the other and so fill at other frames than either vessel.
    pub(crate) const FILLED_A: ([f64; 3], [f64; 3]) = ([0.0, 0.0, -12.0], [0.0, 0.0, 12.0]);
    pub(crate) const FILLED_B: ([f64; 3], [f64; 3]) = ([8.0, 8.0, 12.0], [8.0, 8.0, -12.0]);
    pub(crate) const CROSSING_GHOSTS: [([f64; 3], [f64; 3]); 2] =
        [([0.0, 8.0, -12.0], [0.0, 8.0, 12.0]), ([8.0, 0.0, -12.0], [8.0, 0.0, 12.0])];

    /// The two views of [`FILLED_A`] and [`FILLED_B`]: views, images, arrival maps (the vessels'
    /// centre lines marked) and the box.
    pub(crate) fn opposite_fills() -> (Vec<ConeBeamView>, Vec<Image>, Vec<Image>, BoxMm) {
        use crate::data::synth::arrival::{ArrivalSpec, arrival_map};
        use crate::data::tree::{TreeNode, VesselTree};
        let (a, b) = (FILLED_A, FILLED_B);
        let (_, mut views, _, bounds) = scene();
        views.truncate(2);
        let (_, images) = prior_and_images(a, &[b], &views, &bounds);
        let node = |id, parent, p| TreeNode { id, kind: 0, position_mm: DVec3::from(p), radius_mm: 0.6, parent };
        let tree = VesselTree {
            nodes: vec![node(1, None, a.0), node(2, Some(0), a.1), node(3, None, b.0), node(4, Some(2), b.1)],
        };
        let spec = ArrivalSpec { frames_per_s: 10.0, flow_mm_s: 50.0 };
        let maps: Vec<Image> = views.iter().map(|v| arrival_map(&tree, v, &spec)).collect();
        (views, images, maps, bounds)
    }

    #[test]
    fn arrival_maps_drop_the_ghosts_of_two_views_and_keep_the_vessels() {
        let (views, images, maps, bounds) = opposite_fills();
        let views = &views[..];
        // Every supported voxel a seed (the count is not the question here).
        let cfg = InitConfig { n2: 100_000, n2_mode: SeedMode::AllViewsIntersect, ..InitConfig::default() };
        let seeds = |cfg: &InitConfig| n2_seeds(cfg, views, &images, None, &bounds, 0.4, 7, Some(&maps)).unwrap();
        let ghosts = |s: &[DVec3]| CROSSING_GHOSTS.iter().map(|&g| seeds_on(s, g)).sum::<usize>();
        // Vessel seeds near the centre line (the synthetic maps mark the centre lines' pixels).
        let near = |s: &[DVec3], v: ([f64; 3], [f64; 3])| s.iter().filter(|p| to_segment(**p, v.0, v.1) < 0.5).count();
        let vessels = |s: &[DVec3]| near(s, FILLED_A) + near(s, FILLED_B);
        let (all, checked) = (seeds(&cfg), seeds(&InitConfig { arrival_seeds: true, ..cfg.clone() }));
        eprintln!(
            "ghost seeds {} -> {}, vessel seeds {} -> {}",
            ghosts(&all),
            ghosts(&checked),
            vessels(&all),
            vessels(&checked)
        );
        assert!(ghosts(&all) >= 50 && vessels(&all) >= 50, "the scene has ghosts and vessels to seed: {all:?}");
        assert!(3 * ghosts(&checked) <= ghosts(&all), "ghost seeds {} -> {}", ghosts(&all), ghosts(&checked));
        assert!(10 * vessels(&checked) >= 9 * vessels(&all), "vessel seeds {} -> {}", vessels(&all), vessels(&checked));
        // Three views are not checked (the third view rejects the ghosts), nor are runs without maps.
        let three = InitConfig { arrival_seeds: true, ..cfg.clone() };
        let (_, all_views, _, _) = scene();
        let (_, three_images) = prior_and_images(FILLED_A, &[FILLED_B], &all_views, &bounds);
        let with_maps = n2_seeds(&three, &all_views, &three_images, None, &bounds, 0.4, 7, Some(&maps)).unwrap();
        let without = n2_seeds(&cfg, &all_views, &three_images, None, &bounds, 0.4, 7, None).unwrap();
        assert_eq!(with_maps, without);
        assert_eq!(n2_seeds(&three, views, &images, None, &bounds, 0.4, 7, None).unwrap(), all);
    }

    /// A branch leaving the prior and a vessel floating free of it.
    const BRANCH: ([f64; 3], [f64; 3]) = ([4.0, 0.0, 0.0], [4.0, 8.0, 8.0]);
    const FLOATING: ([f64; 3], [f64; 3]) = ([-8.0, 8.0, -8.0], [-8.0, 8.0, 8.0]);

    /// The scene's views and box with the prior, a branch that leaves it and a floating vessel.
    fn branch_and_floating() -> (TriMesh, Vec<ConeBeamView>, Vec<Image>, BoxMm) {
        let (_, views, _, bounds) = scene();
        let (prior, images) = prior_and_images(PRIOR, &[BRANCH, FLOATING], &views, &bounds);
        (prior, views, images, bounds)
    }

    /// Seeds within 1.5 mm of the segment `s`.
    fn seeds_on(seeds: &[DVec3], s: ([f64; 3], [f64; 3])) -> usize {
        seeds.iter().filter(|p| to_segment(**p, s.0, s.1) < 1.5).count()
    }

    #[test]
    fn seeds_connected_to_the_prior_keep_branches_and_drop_floating_vessels() {
        let (branch, floating) = (BRANCH, FLOATING);
        let (prior, views, images, bounds) = branch_and_floating();
        let seeds_up_to = |reach: f64, max_views: usize| {
            let cfg = InitConfig {
                n2: 2000,
                prior_dilation_px: 1,
                connected_to_prior_mm: reach,
                connected_max_views: max_views,
                // This test is about the prior-connectivity filter alone.
                occluded_views_support: false,
                ..InitConfig::default()
            };
            n2_seeds(&cfg, &views, &images, Some(&prior), &bounds, 0.4, 7, None).unwrap()
        };
        let seeds_with = |reach: f64| seeds_up_to(reach, 3);
        let on = seeds_on;
        let all = seeds_with(0.0);
        assert!(on(&all, floating) > 20 && on(&all, branch) > 20, "both vessels are seeded without the filter");
        let connected = seeds_with(3.0);
        assert_eq!(on(&connected, floating), 0, "the floating vessel is dropped");
        assert!(on(&connected, branch) >= on(&all, branch), "the branch keeps its seeds (and gets the freed ones)");
        assert_eq!(seeds_up_to(3.0, 2), all, "three views are more than connected_max_views: no filter");
    }

    #[test]
    fn seeds_grown_from_the_prior_keep_the_branch_and_drop_the_floating_vessel() {
        let (branch, floating) = (BRANCH, FLOATING);
        let (prior, views, images, bounds) = branch_and_floating();
        let seeds = |n_views: usize, grow_mm: f64| {
            let cfg = InitConfig {
                n2: 2000,
                prior_dilation_px: 1,
                grow_claims_mm: grow_mm,
                grow_claims_n2: 500,
                grow_claims_spacing_mm: 0.4,
                ..InitConfig::default()
            };
            n2_seeds(&cfg, &views[..n_views], &images[..n_views], Some(&prior), &bounds, 0.4, 7, None).unwrap()
        };
        let on = seeds_on;
        let grown = seeds(2, 50.0);
        eprintln!(
            "grown: {} seeds, {} on the branch, {} on the floating vessel",
            grown.len(),
            on(&grown, branch),
            on(&grown, floating)
        );
        assert!(grown.len() <= 500, "grow_claims_n2 caps them");
        assert!(on(&grown, branch) > 20, "the branch grows from the prior");
        assert_eq!(on(&grown, floating), 0, "nothing reaches the floating vessel");
        assert_eq!(seeds(3, 50.0), seeds(3, 0.0), "three views are more than connected_max_views: no growth");
    }

    #[test]
    fn spread_seeds_keep_their_distance_best_first() {
        let sorted: Vec<Scored> =
            (0..20).map(|i| (20.0 - i as f64, DVec3::new(0.25 * i as f64, 0.0, 0.0), true)).collect();
        let kept = spread(sorted.clone(), 1.0, 100);
        // 0, 1.0, 2.0, …, 4.75: every fourth point from the best.
        assert_eq!(kept.iter().map(|s| s.1.x).collect::<Vec<_>>(), vec![0.0, 1.0, 2.0, 3.0, 4.0]);
        assert_eq!(spread(sorted, 1.0, 2).len(), 2, "at most n");
    }

    #[test]
    fn subtracting_the_prior_seeds_the_vessel_behind_it_in_one_of_two_views() {
        // Hidden behind the prior in view 0 along its whole length, visible in view 1.
        let HiddenScene { prior, views, images, bounds, hidden, .. } = hidden_scene(&[4.5]);
        let (views, images) = (&views[..2], &images[..2]);
        let seeds = |subtract_prior: bool| {
            let cfg = InitConfig { n2: 3000, prior_dilation_px: 1, subtract_prior, ..InitConfig::default() };
            n2_seeds(&cfg, views, images, Some(&prior), &bounds, 0.4, 7, None).unwrap()
        };
        let (off, on) = (seeds(false), seeds(true));
        let on_hidden = |s: &[DVec3]| s.iter().filter(|p| to_segment(**p, hidden[0].0, hidden[0].1) < 1.5).count();
        eprintln!(
            "on the hidden vessel: {} of {} seeds without, {} of {} with",
            on_hidden(&off),
            off.len(),
            on_hidden(&on),
            on.len()
        );
        assert_eq!(on_hidden(&off), 0, "view 0 shows no residual where the prior hides the vessel");
        assert!(on_hidden(&on) > 10, "what the prior leaves of view 0 shows it");
        assert!(on_hidden(&on) as f64 >= 0.8 * on.len() as f64, "{} of {} on it", on_hidden(&on), on.len());
        // The images' partial-volume fringe around the prior (brighter than the mesh's chords
        // at its edge) seeds no halo: the chords are taken at their longest within the
        // dilation (without that, three quarters of these seeds lay off the hidden vessel, most of
        // them 1–3 mm from the prior's axis).
        let short = ([-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]);
        let halo = on.iter().filter(|p| to_segment(**p, short.0, short.1) < 2.5).count();
        assert_eq!(halo, 0, "{halo} seeds within 2.5 mm of the prior's axis (radius 1.2 mm)");
    }

    /// A short prior vessel and thin ones parallel to it, hidden behind it in view 0 (shifted
    /// along that view's rays by `shifts` mm); the scene's views, their images and the prior.
    pub(crate) fn hidden_scene(shifts: &[f64]) -> HiddenScene {
        let (_, views, _, bounds) = scene();
        let short = ([-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]);
        let d = -views[0].source_mm().normalize();
        let hidden: Vec<([f64; 3], [f64; 3])> = shifts
            .iter()
            .map(|&k| ((DVec3::from(short.0) + k * d).to_array(), (DVec3::from(short.1) + k * d).to_array()))
            .collect();
        let (prior, images) = prior_and_images(short, &hidden, &views, &bounds);
        let prior_only = prior_and_images(short, &[], &views, &bounds).1;
        HiddenScene { prior, views, images, prior_only, bounds, hidden }
    }

    /// [`hidden_scene`]: the prior mesh, the views, their images, the images of the prior
    /// vessel alone, the box and the hidden vessels.
    pub(crate) struct HiddenScene {
        pub prior: TriMesh,
        pub views: Vec<ConeBeamView>,
        pub images: Vec<Image>,
        pub prior_only: Vec<Image>,
        pub bounds: BoxMm,
        pub hidden: Vec<([f64; 3], [f64; 3])>,
    }

    #[test]
    fn knn_scales_are_the_rms_distance_to_the_nearest_points() {
        let points: Vec<DVec3> = (0..10).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect();
        let s = knn_scales(&points, 2, 9.0);
        assert!((s[5] - 1.0).abs() < 1e-12, "interior point: neighbours at 1 and 1, got {}", s[5]);
        assert!((s[0] - 2.5f64.sqrt()).abs() < 1e-12, "end point: neighbours at 1 and 2, got {}", s[0]);
        assert_eq!(knn_scales(&points[..1], 2, 9.0), vec![9.0]);
    }
}
