//! Where the missing vessels are lost (`ctadsa diagnose`): every point of the missing vessels'
//! centreline (a synthetic case made from a tree) is put in the first class that applies:
//!
//! 1. **found** — the completed surface passes within radius + 0.5 mm (the recall criterion);
//! 2. **not in the masks** — some view's vessel mask (`init.mask_threshold`) misses its pixel,
//!    so nothing image-driven can start there;
//! 3. **behind the prior** — in the masks, but some view's pixel lies in the dilated projection
//!    of the prior, which the residual removes: no N2 seed can start there;
//! 4. **not seeded** — in every residual, yet no N2 seed within [`SEED_RADIUS_MM`] (the image
//!    seeds of every model the run trains: its own, its seed members' and the prior-only
//!    member's tracked ones);
//! 5. **misplaced** — seeded, and in every view the ray through it crosses density above the
//!    iso-level somewhere else (> [`ELSEWHERE_MM`] from the point and from every true vessel):
//!    the views' signal was explained at a wrong depth;
//! 6. **faded** — seeded, but the density there stayed below the iso-level.
//!
//! Each class is a fraction of the missing centreline length. Beside it, where the run's new
//! surface lies ([`crate::eval::new_surface`]) and, for runs that wrote `centreline.swc`, where
//! its new centreline lies ([`crate::eval::new_centreline`]: on a vessel, a ghost the views
//! cannot tell from one, or off the views' vessels).

use std::path::Path;

use ctadsa_render::{ConeBeamView, ViewSet};
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::config::{Config, SeedMode};
use crate::data::case::Case;
use crate::data::case::images::Image;
use crate::data::masks::{Mask, pixel_of, prior_solid, silhouettes, vessel_masks};
use crate::data::mesh::distance::SurfaceIndex;
use crate::data::mesh::io::read_mesh;
use crate::data::run_folder::read_run_summary;
use crate::data::tree::Segment;
use crate::data::tree::swc::read_swc;
use crate::data::volume::Grid;
use crate::data::volume::Volume;
use crate::data::volume::nifti_io::read_nifti;
use crate::error::{CoreError, Result};
use crate::eval::calibre::{CalibreBand, by_calibre};
use crate::eval::metrics::nearest_distances;
use crate::eval::new_centreline::{NewCentreline, new_centreline};
use crate::eval::new_surface::{NewSurface, new_surface};
use crate::eval::score::CaseTruth;
use crate::eval::surface_metrics::{RECALL_SLACK_MM, centreline_points};
use crate::eval::untraced::{Untraced, untraced};
use crate::method::arrival::seed_arrival_maps;
use crate::method::init::initialise;
use crate::method::model::ScaleBounds;
use crate::method::train::{prepare_views, run_working_box};

/// An N2 seed this close (mm) to a centreline point counts as seeding it.
pub const SEED_RADIUS_MM: f64 = 1.5;
/// Density farther than this (mm) from the point and from the true surface is "elsewhere".
pub const ELSEWHERE_MM: f64 = 2.0;

/// Fractions of the missing centreline length in each class (the classes sum to 1;
/// `not_in_masks_seeded` is a part of `not_in_masks`, `behind_prior_seeded` of `behind_prior`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LossBreakdown {
    pub found: f64,
    pub not_in_masks: f64,
    pub behind_prior: f64,
    pub not_seeded: f64,
    pub misplaced: f64,
    pub faded: f64,
    /// The part of `behind_prior` that has an N2 seed within [`SEED_RADIUS_MM`] all the same
    /// (`init.subtract_prior` seeds there): seeded, and lost in training.
    #[serde(default)]
    pub behind_prior_seeded: f64,
    /// The part of `not_in_masks` that has an N2 seed within [`SEED_RADIUS_MM`] all the same
    /// (a seed on the vessel's brighter stretch nearby): seeded, and lost in training.
    #[serde(default)]
    pub not_in_masks_seeded: f64,
    /// Missing centreline length (mm).
    pub length_mm: f64,
}

impl LossBreakdown {
    /// The missing centreline that is not found and has no N2 seed within [`SEED_RADIUS_MM`]:
    /// what no image seed ever reached, whatever the reason.
    pub fn never_seeded(&self) -> f64 {
        (self.not_in_masks - self.not_in_masks_seeded)
            + (self.behind_prior - self.behind_prior_seeded)
            + self.not_seeded
    }
}

/// The diagnosis of a run: where the missing vessels were lost and where its new surface lies.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnosis {
    #[serde(flatten)]
    pub missing: LossBreakdown,
    /// `None` for a case without a prior.
    pub new_surface: Option<NewSurface>,
    /// The missing centreline by true diameter: how much of each band the surface and the
    /// centreline found (absent from diagnoses written before 2026-12-01).
    #[serde(default)]
    pub calibre: Vec<CalibreBand>,
    /// Where the run's new centreline lies; `None` for a run without `centreline.swc`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub new_centreline: Option<NewCentreline>,
    /// The missing centreline the surface finds and the centreline does not, by where the
    /// nearest centreline point lies; `None` for a run without `centreline.swc`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub untraced: Option<Untraced>,
    /// Every classified point of the missing centreline (not in the JSON: `ctadsa diagnose
    /// --points` writes them as CSV).
    #[serde(skip)]
    pub points: Vec<ClassifiedPoint>,
}

/// What the diagnosis looks at.
pub struct DiagnoseInputs<'a> {
    pub views: &'a [ConeBeamView],
    pub images: &'a [Image],
    pub mask_threshold: f64,
    /// Per view: the dilated projection of the prior (what the residual removes).
    pub prior_silhouettes: &'a [Mask],
    /// The N2 seeds (mm).
    pub seeds: &'a [DVec3],
    /// The run's density volume and iso-level.
    pub density: &'a Volume<f32>,
    pub level: f64,
    pub completed: &'a SurfaceIndex,
    pub truth: &'a SurfaceIndex,
}

/// Density of the voxel containing `p` (0 outside the volume).
fn density_at(v: &Volume<f32>, p: DVec3) -> f64 {
    let g = v.grid;
    let ijk: Vec<f64> = (0..3).map(|a| ((p[a] - g.origin_mm[a]) / g.spacing_mm[a]).floor()).collect();
    if ijk.iter().zip(g.dims).any(|(&x, d)| !(x >= 0.0 && x < d as f64)) {
        return 0.0;
    }
    v.get(ijk[0] as usize, ijk[1] as usize, ijk[2] as usize) as f64
}

/// Whether the ray from `view`'s source through `p` crosses above-level density elsewhere.
fn explained_elsewhere(view: &ConeBeamView, p: DVec3, inp: &DiagnoseInputs) -> bool {
    let s = view.source_mm();
    let dir = (p - s).normalize();
    let b = inp.density.grid.bounds();
    let step = inp.density.grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
    // Along the ray, over the span where it can cross the volume's box.
    let reach = (0..3).map(|a| b.size_mm()[a]).fold(0.0f64, |x, y| x.hypot(y));
    let mid = (p - s).length();
    let n = (2.0 * reach / step).ceil() as usize;
    (0..n).any(|k| {
        let q = s + dir * (mid - reach + k as f64 * step);
        (q - p).length() > ELSEWHERE_MM
            && b.contains(q)
            && density_at(inp.density, q) >= inp.level
            && inp.truth.distance(q) > ELSEWHERE_MM
    })
}

/// The class of one missing centreline point (see the module's list).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PointClass {
    Found,
    NotInMasks,
    BehindPrior,
    NotSeeded,
    Misplaced,
    Faded,
}

impl PointClass {
    /// The class's name, as in the JSON and the CSV of `ctadsa diagnose`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Found => "found",
            Self::NotInMasks => "not-in-masks",
            Self::BehindPrior => "behind-prior",
            Self::NotSeeded => "not-seeded",
            Self::Misplaced => "misplaced",
            Self::Faded => "faded",
        }
    }
}

/// One classified point of the missing centreline.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClassifiedPoint {
    /// Position (mm, world) and the true radius there (mm).
    pub position_mm: [f64; 3],
    pub radius_mm: f64,
    /// Centreline length the point stands for (mm).
    pub length_mm: f64,
    pub class: PointClass,
    /// Distance (mm) to the nearest N2 seed and to the completed surface.
    pub to_seed_mm: f64,
    pub to_surface_mm: f64,
    /// The run's density at the point over its iso-level.
    pub density_over_level: f64,
}

/// Classifies the missing centreline (points every ≤ 0.1 mm): the share of each class and the
/// class of every point.
pub fn diagnose(missing: &[Segment], inp: &DiagnoseInputs) -> (LossBreakdown, Vec<ClassifiedPoint>) {
    let masks: Vec<Mask> = vessel_masks(inp.images, inp.mask_threshold);
    let points = centreline_points(missing);
    let centres: Vec<DVec3> = points.iter().map(|p| p.position_mm).collect();
    let to_seed = nearest_distances(&centres, inp.seeds);
    let to_completed = inp.completed.distances(&centres);
    let mut out = LossBreakdown::default();
    let mut classified = Vec::with_capacity(points.len());
    for (k, cp) in points.iter().enumerate() {
        let (p, r, w) = (cp.position_mm, cp.radius_mm, cp.length_mm);
        let px: Vec<Option<usize>> = inp.views.iter().map(|v| pixel_of(v, p)).collect();
        let seeded = to_seed[k] <= SEED_RADIUS_MM;
        let class = if to_completed[k] <= r + RECALL_SLACK_MM {
            PointClass::Found
        } else if px.iter().zip(&masks).any(|(q, m)| !q.is_some_and(|q| m.data[q])) {
            PointClass::NotInMasks
        } else if px.iter().zip(inp.prior_silhouettes).any(|(q, m)| q.is_some_and(|q| m.data[q])) {
            PointClass::BehindPrior
        } else if !seeded {
            PointClass::NotSeeded
        } else if inp.views.iter().all(|v| explained_elsewhere(v, p, inp)) {
            PointClass::Misplaced
        } else {
            PointClass::Faded
        };
        *match class {
            PointClass::Found => &mut out.found,
            PointClass::NotInMasks => {
                if seeded {
                    out.not_in_masks_seeded += w;
                }
                &mut out.not_in_masks
            }
            PointClass::BehindPrior => {
                if seeded {
                    out.behind_prior_seeded += w;
                }
                &mut out.behind_prior
            }
            PointClass::NotSeeded => &mut out.not_seeded,
            PointClass::Misplaced => &mut out.misplaced,
            PointClass::Faded => &mut out.faded,
        } += w;
        out.length_mm += w;
        classified.push(ClassifiedPoint {
            position_mm: p.to_array(),
            radius_mm: r,
            length_mm: w,
            class,
            to_seed_mm: to_seed[k],
            to_surface_mm: to_completed[k],
            density_over_level: density_at(inp.density, p) / inp.level.max(f64::MIN_POSITIVE),
        });
    }
    if out.length_mm > 0.0 {
        let l = out.length_mm;
        for f in [
            &mut out.found,
            &mut out.not_in_masks,
            &mut out.behind_prior,
            &mut out.not_seeded,
            &mut out.misplaced,
            &mut out.faded,
            &mut out.behind_prior_seeded,
            &mut out.not_in_masks_seeded,
        ] {
            *f /= l;
        }
    }
    (out, classified)
}

/// Where the N2 seeds of a configuration fall, before any training: the missing centreline
/// length seeded (a seed within [`SEED_RADIUS_MM`]) or, if not, why not (the classes of
/// [`LossBreakdown`] before training), and what the seeds hit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SeedCoverage {
    /// Fractions of the missing centreline length (they sum to 1).
    pub seeded: f64,
    pub not_in_masks: f64,
    pub behind_prior: f64,
    pub not_seeded: f64,
    /// Missing centreline length (mm).
    pub length_mm: f64,
    /// N2 seeds.
    pub seeds: usize,
    /// Share of the seeds within [`SEED_RADIUS_MM`] of the missing centreline.
    pub on_missing: f64,
    /// Median distance (mm) of those seeds from the missing centreline (NaN for none).
    pub on_missing_offset_mm: f64,
    /// Share of the seeds farther than [`ELSEWHERE_MM`] from every true vessel surface (ghosts).
    pub ghosts: f64,
}

/// Classifies the missing centreline by the seeds alone (`prior_silhouettes` as in
/// [`DiagnoseInputs`]); `truth` is the complete true surface.
pub fn seed_coverage(
    missing: &[Segment],
    views: &[ConeBeamView],
    images: &[Image],
    mask_threshold: f64,
    prior_silhouettes: &[Mask],
    seeds: &[DVec3],
    truth: &SurfaceIndex,
) -> SeedCoverage {
    let masks: Vec<Mask> = vessel_masks(images, mask_threshold);
    let points = centreline_points(missing);
    let centres: Vec<DVec3> = points.iter().map(|p| p.position_mm).collect();
    let to_seed = nearest_distances(&centres, seeds);
    let mut out = SeedCoverage { seeds: seeds.len(), on_missing_offset_mm: f64::NAN, ..SeedCoverage::default() };
    for (k, cp) in points.iter().enumerate() {
        let px: Vec<Option<usize>> = views.iter().map(|v| pixel_of(v, cp.position_mm)).collect();
        let class = if to_seed[k] <= SEED_RADIUS_MM {
            &mut out.seeded
        } else if px.iter().zip(&masks).any(|(q, m)| !q.is_some_and(|q| m.data[q])) {
            &mut out.not_in_masks
        } else if px.iter().zip(prior_silhouettes).any(|(q, m)| q.is_some_and(|q| m.data[q])) {
            &mut out.behind_prior
        } else {
            &mut out.not_seeded
        };
        *class += cp.length_mm;
        out.length_mm += cp.length_mm;
    }
    if out.length_mm > 0.0 {
        let l = out.length_mm;
        for f in [&mut out.seeded, &mut out.not_in_masks, &mut out.behind_prior, &mut out.not_seeded] {
            *f /= l;
        }
    }
    if !seeds.is_empty() {
        let n = seeds.len() as f64;
        let to_missing = nearest_distances(seeds, &centres);
        let mut near: Vec<f64> = to_missing.iter().copied().filter(|&d| d <= SEED_RADIUS_MM).collect();
        out.on_missing = near.len() as f64 / n;
        near.sort_by(f64::total_cmp);
        out.on_missing_offset_mm = near.get(near.len() / 2).copied().unwrap_or(f64::NAN);
        out.ghosts = truth.distances(seeds).iter().filter(|&&d| d > ELSEWHERE_MM).count() as f64 / n;
    }
    out
}

/// A configuration's image seeds on a case: its views and images, the N2 seeds (mm) of every
/// model it trains (the run's, its seed members' and the prior-only member's tracked ones) and
/// the prior's dilated projections.
struct Seeding {
    views: ViewSet,
    images: Vec<Image>,
    seeds: Vec<DVec3>,
    prior_silhouettes: Vec<Mask>,
}

/// The [`Seeding`] of configuration `cfg` on `case`.
fn seeds_of(case: &Case, cfg: &Config) -> Result<Seeding> {
    let (views, images) = prepare_views(case, cfg)?;
    let prior = case.prior_mesh()?;
    let working_box = run_working_box(case, cfg, &views, &images, prior.as_ref())?;
    let h = case.file.volume.voxel_mm;
    let bounds = ScaleBounds::from_voxel(h, cfg.model.scale_min_voxels, cfg.model.scale_max_voxels);
    let mut models = vec![cfg.clone()];
    models.extend(cfg.seed_members());
    models.extend(cfg.prior_only_member().filter(|m| m.init.n2_mode != SeedMode::None));
    let mut seeds: Vec<DVec3> = Vec::new();
    for m in &models {
        let arrival = if m.init.checks_arrival() { seed_arrival_maps(case, m)? } else { None };
        let init = initialise(
            &m.init,
            views.views(),
            &images,
            prior.as_ref(),
            &working_box,
            h,
            bounds,
            m.run.seed,
            arrival.as_deref(),
        )?;
        seeds.extend(
            init.gaussians.means[3 * init.n1..]
                .chunks_exact(3)
                .map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)),
        );
    }
    let prior_silhouettes: Vec<Mask> = match &prior {
        Some(p) => silhouettes(&prior_solid(p, Grid::covering(&working_box, h)?), views.views())
            .into_iter()
            .map(|m| m.dilated(cfg.init.prior_dilation_px))
            .collect(),
        None => {
            images.iter().map(|i| Mask { width: i.width, height: i.height, data: vec![false; i.data.len()] }).collect()
        }
    };
    Ok(Seeding { views, images, seeds, prior_silhouettes })
}

/// [`seed_coverage`] of configuration `cfg` on a synthetic `case` with a tree (no run needed).
pub fn diagnose_seeds(case: &Case, cfg: &Config) -> Result<SeedCoverage> {
    let truth = CaseTruth::load(case)?.ok_or_else(|| CoreError::invalid("the case has no ground truth"))?;
    let missing = truth
        .missing_centreline
        .as_ref()
        .ok_or_else(|| CoreError::invalid("the case has no centreline tree (gt/tree.swc) and prior threshold"))?;
    let Seeding { views, images, seeds, prior_silhouettes } = seeds_of(case, cfg)?;
    let truth_index = SurfaceIndex::new(&truth.complete);
    Ok(seed_coverage(
        missing,
        views.views(),
        &images,
        cfg.init.mask_threshold,
        &prior_silhouettes,
        &seeds,
        &truth_index,
    ))
}

/// [`diagnose`] and [`new_surface`] of a finished run (`run_dir` with `config.toml`,
/// `density.nii.gz`, `summary.json` and the completed mesh) on its synthetic case, which must
/// have a tree.
pub fn diagnose_run(case: &Case, run_dir: &Path) -> Result<Diagnosis> {
    let summary_path = run_dir.join("summary.json");
    let summary = read_run_summary(run_dir)?;
    // Another case's truth would classify the run's vessels silently wrong (summaries written
    // before 2026-11-30 carry no fingerprint).
    if let Some(made_on) = summary["case_fingerprint"].as_str()
        && made_on != case.fingerprint()
    {
        return Err(CoreError::format(
            &summary_path,
            format!(
                "the run was made on case `{made_on}`, not on {} (`{}`: name and a hash of case.json); diagnose \
                 it with its own case",
                case.dir.display(),
                case.fingerprint()
            ),
        ));
    }
    let cfg = Config::load(Some(&run_dir.join("config.toml")), &[])?;
    let truth = CaseTruth::load(case)?.ok_or_else(|| CoreError::invalid("the case has no ground truth"))?;
    let missing = truth
        .missing_centreline
        .as_ref()
        .ok_or_else(|| CoreError::invalid("the case has no centreline tree (gt/tree.swc) and prior threshold"))?;
    let Seeding { views, images, seeds, prior_silhouettes } = seeds_of(case, &cfg)?;
    let prior = case.prior_mesh()?;
    let density = read_nifti(&run_dir.join("density.nii.gz"))?;
    let level = summary["mc_level"]
        .as_f64()
        .ok_or_else(|| CoreError::format(&summary_path, "no `mc_level` in the run summary"))?;
    let completed = read_mesh(&run_dir.join(format!("mesh.{}", cfg.output.mesh_format)))?;
    let truth_index = SurfaceIndex::new(&truth.complete);
    let missing_area = truth.split.as_ref().map(|(_, m)| m.area_mm2());
    let new = prior.as_ref().map(|p| new_surface(&completed, &SurfaceIndex::new(p), &truth_index, missing_area));
    let inputs = DiagnoseInputs {
        views: views.views(),
        images: &images,
        mask_threshold: cfg.init.mask_threshold,
        prior_silhouettes: &prior_silhouettes,
        seeds: &seeds,
        density: &density,
        level,
        completed: &SurfaceIndex::new(&completed),
        truth: &truth_index,
    };
    let (missing, points) = diagnose(missing, &inputs);
    let swc = run_dir.join("centreline.swc");
    let centreline = if swc.exists() { Some(read_swc(&swc)?.tree) } else { None };
    let new_centreline = match (&centreline, &truth.centreline) {
        (Some(tree), Some(whole)) => {
            let masks: Vec<Mask> = vessel_masks(&images, cfg.init.mask_threshold);
            Some(new_centreline(tree, whole, views.views(), &masks))
        }
        _ => None,
    };
    let calibre = by_calibre(&points, centreline.as_ref());
    let untraced = centreline.as_ref().map(|tree| untraced(&points, tree));
    Ok(Diagnosis { missing, new_surface: new, calibre, new_centreline, untraced, points })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn never_seeded_counts_the_unfound_classes_less_their_seeded_parts() {
        let b = LossBreakdown {
            found: 0.6,
            not_in_masks: 0.1,
            not_in_masks_seeded: 0.04,
            behind_prior: 0.2,
            behind_prior_seeded: 0.05,
            not_seeded: 0.03,
            misplaced: 0.01,
            faded: 0.06,
            length_mm: 100.0,
        };
        // 0.06 faint + 0.15 behind the prior + 0.03 in every residual; the misplaced and faded
        // points were seeded.
        assert!((b.never_seeded() - 0.24).abs() < 1e-12, "{}", b.never_seeded());
    }

    #[test]
    fn point_class_names_are_the_json_names() {
        for c in [
            PointClass::Found,
            PointClass::NotInMasks,
            PointClass::BehindPrior,
            PointClass::NotSeeded,
            PointClass::Misplaced,
            PointClass::Faded,
        ] {
            assert_eq!(serde_json::to_value(c).unwrap(), c.name());
        }
    }
}
