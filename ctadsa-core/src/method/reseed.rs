//! Re-seeding from what the model does not explain: the views rendered from the current model,
//! each view's residual `target − render` masked where it exceeds the view's vessel level, and
//! new centres placed where every view's residual mask agrees — the image seeding of
//! [`crate::method::init`] run again on the residuals. The prior's pixels are not lost to it:
//! once the model draws the prior, a vessel in front of or behind it shows in the residual; a
//! vessel the first seeds missed (faint, or cut off by the prior's projection) gets a second chance.

use std::borrow::Cow;

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::config::InitConfig;
use crate::data::case::images::Image;
use crate::data::masks::{Mask, silhouettes};
use crate::data::vessel_evidence::VesselEvidence;
use crate::data::volume::{BoxMm, Grid, Volume};
use crate::error::Result;
use crate::method::init::{arrival_pair, arriving, back_project, best_centres, connected_to_anchors};

/// What re-seeding looks at.
pub struct ResidualInputs<'a> {
    pub views: &'a [ConeBeamView],
    /// The views' target images.
    pub targets: &'a [Image],
    /// The current model's render of every view, `H × W` each, as `targets`.
    pub renders: &'a [Vec<f32>],
    /// The prior as solid voxels on the seeding grid, if there is a prior.
    pub prior: Option<&'a Volume<u8>>,
    /// The box to seed in and the voxel of the seeding grid (mm).
    pub bounds: &'a BoxMm,
    pub voxel_mm: f64,
    /// Voxels of the seeding grid that hold what the model already draws (e.g. its denser
    /// Gaussians): with the prior, what new seeds may connect to (`None`: the prior alone).
    pub drawn: Option<&'a Volume<u8>>,
    /// The views' arrival maps, when the case has them (checked with `init.arrival_reseeds`).
    pub arrival: Option<&'a [Image]>,
}

/// The two views' arrival maps where they check the re-seeds (`init.arrival_reseeds`, two views,
/// maps for both).
pub(crate) fn reseed_arrival_maps<'m>(
    cfg: &InitConfig,
    views: &[ConeBeamView],
    arrival: Option<&'m [Image]>,
) -> Option<&'m [Image]> {
    arrival_pair(cfg, views, arrival).filter(|_| cfg.arrival_reseeds)
}

/// Up to `n` new centres (mm) in the inputs' box where every view's residual exceeds
/// `mask_threshold` × the view's vessel level, outside the prior, spaced as the image seeds
/// ([`InitConfig::seed_spacing_mm_for`] the number of views; 0: the best-scored voxels), kept
/// connected to the prior as the image seeds are (`cfg.connected_to_prior_mm` for runs of at
/// most `cfg.connected_max_views` views). With
/// `occluded_support`, a view whose pixel lies in the prior's dilated projection supports a
/// voxel where its target shows a vessel, if at least half of the views show residual. With
/// `cfg.arrival_reseeds`, two views and arrival maps, a voxel is kept only where both views fill
/// at once ([`crate::method::arrival::arrives_together`]).
pub fn residual_seeds(
    cfg: &InitConfig,
    inputs: &ResidualInputs,
    mask_threshold: f64,
    occluded_support: bool,
    n: usize,
    seed: u64,
) -> Result<Vec<DVec3>> {
    if n == 0 {
        return Ok(Vec::new());
    }
    let grid = Grid::covering(inputs.bounds, inputs.voxel_mm)?;
    let residuals: Vec<Image> = inputs
        .targets
        .iter()
        .zip(inputs.renders)
        .map(|(t, r)| Image { data: t.data.iter().zip(r).map(|(&a, &b)| a - b).collect(), ..t.clone() })
        .collect();
    // Each view's residual read as its target is (pooled along the vessels where noisy), against
    // the target's vessel level.
    let evidence: Vec<VesselEvidence> = VesselEvidence::of_views(inputs.targets);
    let residuals: Vec<Image> = residuals.into_iter().zip(&evidence).map(|(r, e)| e.read(r)).collect();
    let support: Vec<Mask> = residuals
        .iter()
        .zip(&evidence)
        .map(|(res, target)| {
            let level = target.level(mask_threshold);
            let data = res.data.iter().map(|&v| v as f64 > level && v > 0.0).collect();
            Mask { width: res.width, height: res.height, data }.dilated(cfg.residual_dilation_px)
        })
        .collect();
    let prior = inputs.prior.filter(|p| p.grid == grid);
    // Where the prior hides a pixel, the model may draw a vessel behind it as a brighter prior:
    // the view then supports a voxel without residual (when its target shows a vessel there),
    // provided half of the views see residual.
    let occluded: Option<Vec<Mask>> = prior.filter(|_| occluded_support).map(|p| {
        silhouettes(p, inputs.views)
            .iter()
            .zip(&evidence)
            .map(|(sil, t)| {
                t.mask(mask_threshold).dilated(cfg.residual_dilation_px).and(&sil.dilated(cfg.prior_dilation_px))
            })
            .collect()
    });
    let mut scored = back_project(&grid, inputs.views, &support, occluded.as_deref(), &residuals, prior, true);
    if let Some(maps) = reseed_arrival_maps(cfg, inputs.views, inputs.arrival) {
        scored = arriving(cfg, inputs.views, maps, scored);
    }
    if let Some(p) = prior
        && cfg.connected_to_prior_mm > 0.0
        && inputs.views.len() <= cfg.connected_max_views
    {
        // A vessel grows from what is there: the prior, and what the model already draws.
        let reachable = match inputs.drawn.filter(|d| d.grid == grid) {
            Some(d) => Cow::Owned(Volume {
                grid,
                index_to_world: p.index_to_world,
                data: p.data.iter().zip(&d.data).map(|(&a, &b)| a.max(b)).collect(),
            }),
            None => Cow::Borrowed(p),
        };
        scored = connected_to_anchors(scored, &reachable, cfg.connected_to_prior_mm, |_| false);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x2e5eed);
    Ok(best_centres(scored, cfg.seed_spacing_mm_for(inputs.views.len()), n, inputs.voxel_mm, &mut rng))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::masks::prior_solid;
    use crate::method::init::tests::{HiddenScene, hidden_scene, to_segment};

    #[test]
    fn a_vessel_behind_the_prior_is_seeded_once_the_model_draws_the_prior() {
        let HiddenScene { prior, views, images, prior_only, bounds, hidden } = hidden_scene(&[4.5]);
        let (views, images) = (&views[..2], &images[..2]);
        let grid = Grid::covering(&bounds, 0.4).unwrap();
        let solid = prior_solid(&prior, grid);
        // A model that draws exactly the prior vessel renders its images.
        let renders: Vec<Vec<f32>> = prior_only[..2].iter().map(|i| i.data.clone()).collect();
        // The hidden vessel floats 4.5 mm from the prior: no connectivity filter.
        let cfg = InitConfig { connected_to_prior_mm: 0.0, ..InitConfig::default() };
        let inputs = ResidualInputs {
            views,
            targets: images,
            renders: &renders,
            prior: Some(&solid),
            bounds: &bounds,
            voxel_mm: 0.4,
            drawn: None,
            arrival: None,
        };
        let seeds = residual_seeds(&cfg, &inputs, 0.05, false, 500, 7).unwrap();
        let on = seeds.iter().filter(|p| to_segment(**p, hidden[0].0, hidden[0].1) < 1.5).count();
        eprintln!("re-seeded: {on} of {} on the hidden vessel", seeds.len());
        assert!(on > 10, "the residual shows the hidden vessel");
        assert!(on as f64 >= 0.8 * seeds.len() as f64, "{on} of {} on it", seeds.len());
        // A model that already draws everything leaves nothing to seed.
        let all: Vec<Vec<f32>> = images.iter().map(|i| i.data.clone()).collect();
        let inputs = ResidualInputs { renders: &all, ..inputs };
        assert!(residual_seeds(&cfg, &inputs, 0.05, false, 500, 7).unwrap().is_empty());
    }

    #[test]
    fn a_vessel_drawn_as_a_brighter_prior_is_seeded_with_occluded_support() {
        let HiddenScene { prior, views, images, prior_only, bounds, hidden } = hidden_scene(&[4.5]);
        let (views, images) = (&views[..2], &images[..2]);
        let solid = prior_solid(&prior, Grid::covering(&bounds, 0.4).unwrap());
        // View 0, where the vessel hides behind the prior, is drawn exactly (the model made the
        // prior brighter there); view 1 shows the vessel as residual.
        let renders = vec![images[0].data.clone(), prior_only[1].data.clone()];
        let cfg = InitConfig { connected_to_prior_mm: 0.0, ..InitConfig::default() };
        let inputs = ResidualInputs {
            views,
            targets: images,
            renders: &renders,
            prior: Some(&solid),
            bounds: &bounds,
            voxel_mm: 0.4,
            drawn: None,
            arrival: None,
        };
        let seeds = |occluded: bool| residual_seeds(&cfg, &inputs, 0.05, occluded, 500, 7).unwrap();
        let on = |s: &[DVec3]| s.iter().filter(|p| to_segment(**p, hidden[0].0, hidden[0].1) < 1.5).count();
        let (without, with) = (seeds(false), seeds(true));
        eprintln!(
            "occluded support: {} of {} on the hidden vessel (without: {})",
            on(&with),
            with.len(),
            without.len()
        );
        assert!(without.is_empty(), "no residual in view 0: nothing to intersect");
        assert!(on(&with) > 10 && on(&with) as f64 >= 0.8 * with.len() as f64, "{} of {}", on(&with), with.len());
    }

    /// With `init.arrival_reseeds`, the re-seeds of a model that draws nothing yet (its residual
    /// the whole target) keep off the ghosts where two vessels filled at other times cross.
    #[test]
    fn arrival_maps_keep_the_reseeds_off_the_ghosts() {
        use crate::method::init::tests::{CROSSING_GHOSTS, FILLED_A, FILLED_B, opposite_fills};
        let (views, images, maps, bounds) = opposite_fills();
        let blank: Vec<Vec<f32>> = images.iter().map(|i| vec![0.0; i.data.len()]).collect();
        let inputs = ResidualInputs {
            views: &views,
            targets: &images,
            renders: &blank,
            prior: None,
            bounds: &bounds,
            voxel_mm: 0.4,
            drawn: None,
            arrival: Some(&maps),
        };
        let cfg = InitConfig { connected_to_prior_mm: 0.0, seed_spacing_mm: 0.0, ..InitConfig::default() };
        let seeds = |cfg: &InitConfig| residual_seeds(cfg, &inputs, 0.05, false, 100_000, 7).unwrap();
        let on = |s: &[DVec3], segments: &[([f64; 3], [f64; 3])], within_mm: f64| {
            s.iter().filter(|p| segments.iter().any(|g| to_segment(**p, g.0, g.1) < within_mm)).count()
        };
        let (all, checked) = (seeds(&cfg), seeds(&InitConfig { arrival_reseeds: true, ..cfg.clone() }));
        // Vessel re-seeds near the centre lines (the synthetic maps mark the centre lines' pixels).
        let ghosts = |s: &[DVec3]| on(s, &CROSSING_GHOSTS, 1.5);
        let vessels = |s: &[DVec3]| on(s, &[FILLED_A, FILLED_B], 0.5);
        eprintln!(
            "re-seeds on ghosts {} -> {}, on the vessels {} -> {}",
            ghosts(&all),
            ghosts(&checked),
            vessels(&all),
            vessels(&checked)
        );
        assert!(
            ghosts(&all) >= 50 && vessels(&all) >= 50,
            "ghosts and vessels to seed: {} / {}",
            ghosts(&all),
            vessels(&all)
        );
        assert!(3 * ghosts(&checked) <= ghosts(&all), "ghost re-seeds {} -> {}", ghosts(&all), ghosts(&checked));
        assert!(
            10 * vessels(&checked) >= 9 * vessels(&all),
            "vessel re-seeds {} -> {}",
            vessels(&all),
            vessels(&checked)
        );
        // Without maps, or with the check off, the re-seeds are as before.
        assert_eq!(
            residual_seeds(&cfg, &ResidualInputs { arrival: None, ..inputs }, 0.05, false, 100_000, 7).unwrap(),
            all
        );
    }
}
