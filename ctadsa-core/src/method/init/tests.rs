use super::select::spread;
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
fn residual_seeds_find_a_vessel_below_the_per_pixel_noise_floor() {
    let (prior, views, clean, bounds) = scene();
    // Noise at 0.6 × the missing vessel's brightest pixel: the per-pixel 3 σ floor lies above the
    // whole vessel (no seed at all on the per-pixel masks); pooled along it the vessel stands out.
    let (_, prior_only) = prior_and_images(PRIOR, &[], &views, &bounds);
    let missing_only: Vec<Image> = clean
        .iter()
        .zip(&prior_only)
        .map(|(a, b)| Image { data: a.data.iter().zip(&b.data).map(|(x, y)| x - y).collect(), ..a.clone() })
        .collect();
    let peak = missing_only.iter().map(Image::max).fold(0.0f32, f32::max) as f64;
    let sigma = 0.6 * peak;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let noisy: Vec<Image> = clean
        .iter()
        .map(|img| Image {
            data: img
                .data
                .iter()
                .map(|&v| (v as f64 + sigma * crate::data::projector::noise::standard_normal(&mut rng)) as f32)
                .collect(),
            ..img.clone()
        })
        .collect();
    assert!(missing_only.iter().all(|m| (m.max() as f64) < crate::data::masks::NOISE_FLOOR_SIGMAS * sigma));
    let cfg = InitConfig { n2: 300, prior_dilation_px: 1, connected_to_prior_mm: 0.0, ..InitConfig::default() };
    let seeds = n2_seeds(&cfg, &views, &noisy, Some(&prior), &bounds, 0.4, 7, None).unwrap();
    let on_missing = seeds.iter().filter(|p| to_segment(**p, MISSING.0, MISSING.1) < 1.5).count();
    // The share of the vessel's axis (every 0.5 mm) with a seed within 1 mm.
    let (a, b) = (DVec3::from(MISSING.0), DVec3::from(MISSING.1));
    let axis: Vec<DVec3> = (0..=32).map(|i| a + (b - a) * (i as f64 / 32.0)).collect();
    let covered = axis.iter().filter(|q| seeds.iter().any(|p| p.distance(**q) < 1.0)).count();
    eprintln!(
        "noisy residual seeds: {on_missing} of {} on the missing vessel, {covered} of 33 axis points",
        seeds.len()
    );
    assert!(seeds.len() >= 50, "only {} seeds", seeds.len());
    assert!(on_missing as f64 >= 0.7 * seeds.len() as f64, "{on_missing} of {} on the missing vessel", seeds.len());
    assert!(covered >= 10, "{covered} of 33 points of the vessel's axis seeded");
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
    let spec = ArrivalSpec::ideal(10.0, 50.0);
    let maps: Vec<Image> = views.iter().enumerate().map(|(i, v)| arrival_map(&tree, v, i, &spec)).collect();
    let mut shifted = maps.clone();
    shifted[1].data.iter_mut().filter(|f| **f >= 0.0).for_each(|f| *f += 5.0);
    let cfg = InitConfig { arrival_track_starts: true, ..tracks_only() };
    let seeds = |maps: Option<&[Image]>| n2_seeds(&cfg, views, &images, Some(&prior), &bounds, 0.4, 7, maps).unwrap();
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
    let seeds = |cfg: &InitConfig| n2_seeds(cfg, &views[..2], &images, Some(&prior), &bounds, 0.4, 7, None).unwrap();
    let base = tracks_only();
    let fitted = InitConfig { fit_prior_projection: true, prior_dilation_px: 0, ..base.clone() };
    let own = InitConfig { track_fit_prior_projection: Some(true), track_prior_dilation_px: Some(0), ..base.clone() };
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
    let cfg =
        InitConfig { n2: 400, n2_two_views: Some(50), n2_mode: SeedMode::AllViewsIntersect, ..InitConfig::default() };
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
    let spec = ArrivalSpec::ideal(10.0, 50.0);
    let maps: Vec<Image> = views.iter().enumerate().map(|(i, v)| arrival_map(&tree, v, i, &spec)).collect();
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
    let sorted: Vec<Scored> = (0..20).map(|i| (20.0 - i as f64, DVec3::new(0.25 * i as f64, 0.0, 0.0), true)).collect();
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
