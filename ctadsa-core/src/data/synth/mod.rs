//! Synthetic cases: anatomy (a vessel tree or a label volume) → occupancy volume → complete,
//! prior and missing meshes → DSA views by the independent voxel projector → a case folder.

pub mod arrival;
pub mod presets;

use std::path::{Path, PathBuf};

use ctadsa_render::{ConeBeamView, TigreGeometry};
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::data::case::images::{Image, write_png16, write_preview_png, write_rgb_or_grey, write_tiff_f32};
use crate::data::case::{
    CASE_FILE, CASE_FORMAT, CASE_VERSION, CaseFile, GroundTruth, ImageValues, PriorEntry, Provenance, ViewEntry,
    ViewGeometry, VolumeEntry,
};
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::write_mesh;
use crate::data::mesh::marching::extract_isosurface;
use crate::data::mesh::render_png::{Coloured, standard_views, write_mesh_png};
use crate::data::projector::correction::{PoseCorrection, corrected_view, random_correction};
use crate::data::projector::noise::NoiseModel;
use crate::data::projector::project_volume;
use crate::data::tree::VesselTree;
use crate::data::tree::prior::{PriorThreshold, split_by_diameter};
use crate::data::tree::procedural::ProceduralTree;
use crate::data::tree::swc::{read_swc, write_swc};
use crate::data::volume::edt::local_thickness;
use crate::data::volume::nifti_io::{read_nifti, write_nifti};
use crate::data::volume::rasterize::rasterize_segments;
use crate::data::volume::{BoxMm, Grid, Volume};
use crate::error::{CoreError, Result, remove_path, write_file};
use arrival::{ArrivalSpec, arrival_map};
use presets::{GeometryPreset, view_preset};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Where the vessels come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Anatomy {
    /// The built-in procedural tree.
    Procedural(ProceduralTree),
    /// A centreline tree from an SWC file.
    Swc { path: PathBuf },
    /// A label volume (NIfTI); `labels` selects label values (empty: every non-zero label).
    /// `prior_drop_labels` are left out of the prior whatever their thickness: whole named
    /// branches (e.g. the communicating arteries) become the missing vessels.
    Labels {
        path: PathBuf,
        #[serde(default)]
        labels: Vec<u32>,
        #[serde(default)]
        prior_drop_labels: Vec<u32>,
    },
}

/// Everything `ctadsa synth` needs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SynthConfig {
    pub name: String,
    pub anatomy: Anatomy,
    /// Rigid rotation (degrees about x, then y, then z) applied after centring.
    #[serde(default)]
    pub rotation_deg: [f64; 3],
    /// Translation (mm) applied after the rotation.
    #[serde(default)]
    pub translation_mm: [f64; 3],
    /// Voxel size (mm); `None`: 256 voxels along the longest side of the anatomy's box
    /// (trees; label volumes keep their own grid).
    #[serde(default)]
    pub voxel_mm: Option<f64>,
    /// Sub-samples per voxel edge for tube occupancy (trees).
    pub supersample: usize,
    /// View preset (`ap-lat`, `ap-lat-oblique`, `angles:…`).
    pub views: String,
    pub geometry: GeometryPreset,
    /// Detector binning (1 = native pixels).
    pub binning: u32,
    /// Detector size (pixels per side, before binning) instead of the preset's; the pixel
    /// pitch stays the preset's, so a smaller detector is a centred crop.
    #[serde(default)]
    pub detector_px: Option<u32>,
    /// DSA value per mm of vessel path.
    pub contrast_per_mm: f64,
    pub noise: NoiseModel,
    /// Divide the images by their maximum over all views (recorded in the case).
    pub normalise: bool,
    /// Prior thresholds; the first is the case's prior, all are written under `priors/`.
    pub priors: Vec<PriorThreshold>,
    /// Simulated registration error: every view but the first is imaged with a pose moved by
    /// this much, while the case records the nominal pose (the truth goes to ground truth).
    #[serde(default)]
    pub pose_error: Option<PoseErrorSpec>,
    /// A time-resolved run: each view also gets an arrival map ([`arrival::arrival_map`]; trees
    /// only).
    #[serde(default)]
    pub arrival: Option<ArrivalSpec>,
}

/// Size of a simulated pose error per view.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseErrorSpec {
    /// Translation (mm) in a random direction.
    pub translation_mm: f64,
    /// Rotation (degrees) about a random axis through the isocentre.
    pub rotation_deg: f64,
    pub seed: u64,
}

/// Upper bound of [`SynthConfig::supersample`] (16³ sub-samples per voxel).
pub const MAX_SUPERSAMPLE: usize = 16;

impl SynthConfig {
    /// Range checks of the settings; the error names the setting.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, problem: String| Err(CoreError::invalid(format!("{what}: {problem}")));
        if !(self.contrast_per_mm.is_finite() && self.contrast_per_mm > 0.0) {
            return bad("contrast", format!("must be positive, got {}", self.contrast_per_mm));
        }
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return bad("supersample", format!("must be in 1..={MAX_SUPERSAMPLE}, got {}", self.supersample));
        }
        if let Some(v) = self.voxel_mm
            && !(v.is_finite() && v > 0.0)
        {
            return bad("voxel size", format!("must be a positive number of mm, got {v}"));
        }
        let native = self.detector_px.unwrap_or(self.geometry.geometry(0.0, 0.0, 1).detector_px[0]);
        if self.binning < 1 || self.binning > native {
            return bad(
                "binning",
                format!("must be in 1..={native} (the detector's pixels per side), got {}", self.binning),
            );
        }
        if let Some(n) = self.noise.poisson_photons
            && !(n.is_finite() && n > 0.0)
        {
            return bad("noise photons", format!("must be a positive number, got {n}"));
        }
        if let Some(sd) = self.noise.gaussian_sigma
            && !(sd.is_finite() && sd >= 0.0)
        {
            return bad("noise sigma", format!("must be ≥ 0, got {sd}"));
        }
        if let Some(mu) = self.noise.attenuation
            && !(mu.is_finite() && mu > 0.0)
        {
            return bad("noise attenuation", format!("must be positive, got {mu}"));
        }
        if !self.rotation_deg.iter().chain(&self.translation_mm).all(|v| v.is_finite()) {
            return bad("rotation/translation", "must be finite".into());
        }
        if let Some(e) = self.pose_error
            && !(e.translation_mm.is_finite() && e.rotation_deg.is_finite())
        {
            return bad("pose error", "must be finite".into());
        }
        if let Some(a) = &self.arrival {
            a.validate()?;
            if matches!(self.anatomy, Anatomy::Labels { .. }) {
                return bad("arrival maps", "need a tree (SWC or the procedural one), not a label volume".into());
            }
        }
        Ok(())
    }

    /// A small case for tests and quick checks: a procedural tree of 24 terminals in a
    /// 40 × 40 × 32 mm box, three views of 96 × 96 pixels of 1 mm (192 px binned by 2), 0.4 mm
    /// voxels, prior = vessels ≥ 1.5 mm.
    pub fn small_procedural(name: &str) -> Self {
        Self {
            name: name.into(),
            anatomy: Anatomy::Procedural(ProceduralTree {
                seed: 7,
                terminals: 24,
                domain_mm: [20.0, 20.0, 16.0],
                terminal_radius_mm: 0.45,
                murray_exponent: 3.0,
            }),
            detector_px: Some(192),
            binning: 2,
            voxel_mm: Some(0.4),
            ..Self::default()
        }
    }
}

impl SynthConfig {
    /// The demo's case: the built-in procedural tree, three views (AP, LAT, oblique) on a
    /// cropped reference detector (256² of 0.5 mm, binned to 128² of 1 mm), prior = vessels
    /// ≥ 1.5 mm.
    pub fn demo() -> Self {
        Self {
            name: "demo-procedural".into(),
            anatomy: Anatomy::Procedural(ProceduralTree::default()),
            detector_px: Some(256),
            binning: 2,
            voxel_mm: Some(0.35),
            ..Self::default()
        }
    }
}

impl Default for SynthConfig {
    fn default() -> Self {
        Self {
            name: "procedural".into(),
            anatomy: Anatomy::Procedural(ProceduralTree::default()),
            rotation_deg: [0.0; 3],
            translation_mm: [0.0; 3],
            voxel_mm: None,
            supersample: 2,
            views: "ap-lat-oblique".into(),
            geometry: GeometryPreset::Reference,
            binning: 1,
            detector_px: None,
            contrast_per_mm: 1.0,
            noise: NoiseModel::default(),
            normalise: false,
            priors: vec![PriorThreshold::DiameterMm(1.5)],
            pose_error: None,
            arrival: None,
        }
    }
}

/// What a synthesis produced, for reports.
#[derive(Debug, Clone, Serialize)]
pub struct SynthSummary {
    pub dir: PathBuf,
    pub voxels: [usize; 3],
    pub voxel_mm: [f64; 3],
    pub views: usize,
    pub prior_thresholds_mm: Vec<f64>,
    /// Vessel volume (mm³) of the complete anatomy and of the first prior.
    pub complete_volume_mm3: f64,
    pub prior_volume_mm3: f64,
    pub warnings: Vec<String>,
}

fn rotation(deg: [f64; 3]) -> DMat3 {
    let [x, y, z] = deg.map(f64::to_radians);
    DMat3::from_rotation_z(z) * DMat3::from_rotation_y(y) * DMat3::from_rotation_x(x)
}

/// The anatomy as occupancy volumes: complete and, per prior threshold, prior.
struct Rasterised {
    complete: Volume<f32>,
    priors: Vec<(f64, Volume<f32>)>,
    tree: Option<VesselTree>,
    source: String,
    warnings: Vec<String>,
}

fn from_tree(mut tree: VesselTree, cfg: &SynthConfig, source: String, warnings: Vec<String>) -> Result<Rasterised> {
    if tree.segments().is_empty() {
        let why = warnings.first().map_or(String::new(), |w| format!("; first problem: {w}"));
        return Err(CoreError::invalid(format!(
            "the tree has no vessel segment ({} nodes, none with a usable parent){why}",
            tree.nodes.len()
        )));
    }
    tree.centre_on_isocentre();
    tree.transform(rotation(cfg.rotation_deg), DVec3::from(cfg.translation_mm));
    let (lo, hi) = tree.bounds_mm().ok_or_else(|| CoreError::invalid("the tree is empty"))?;
    let bounds = BoxMm { min_mm: lo.to_array(), max_mm: hi.to_array() }.padded(1.0);
    let grid = match cfg.voxel_mm {
        Some(v) => Grid::covering(&bounds, v)?,
        None => Grid::with_longest_side(&bounds, 256)?,
    };
    let complete = rasterize_segments(&tree.segments(), grid, cfg.supersample);
    let mut priors = Vec::new();
    for t in &cfg.priors {
        let d = t.diameter_mm(&tree)?;
        let split = split_by_diameter(&tree, d);
        priors.push((d, rasterize_segments(&split.prior, grid, cfg.supersample)));
    }
    Ok(Rasterised { complete, priors, tree: Some(tree), source, warnings })
}

fn from_labels(path: &Path, labels: &[u32], prior_drop_labels: &[u32], cfg: &SynthConfig) -> Result<Rasterised> {
    if cfg.rotation_deg != [0.0; 3] || cfg.translation_mm != [0.0; 3] {
        return Err(CoreError::invalid(
            "rotation/translation are supported for trees only; resample a label volume before synthesis",
        ));
    }
    let vol = read_nifti(path)?;
    let selected: Vec<u8> = vol
        .data
        .iter()
        .map(|&v| {
            let l = v.round() as i64;
            (l > 0 && (labels.is_empty() || labels.contains(&(l as u32)))) as u8
        })
        .collect();
    if !selected.contains(&1) {
        return Err(CoreError::format(path, format!("no voxel carries the selected labels {labels:?}")));
    }
    let dropped: Vec<bool> =
        vol.data.iter().map(|&v| prior_drop_labels.contains(&(v.round().max(0.0) as u32))).collect();
    if let Some(l) = prior_drop_labels.iter().find(|&&l| !vol.data.iter().any(|&v| v.round() == l as f32)) {
        return Err(CoreError::format(path, format!("no voxel carries label {l}, which the prior should leave out")));
    }
    // Axis-aligned on the file's voxel sizes, centred on the isocentre (the direction matrix is
    // ignored, as in the reference implementation).
    let mut grid = vol.grid;
    let size = [0, 1, 2].map(|a| grid.dims[a] as f64 * grid.spacing_mm[a]);
    grid.origin_mm = size.map(|s| -s / 2.0);
    let mask = Volume { grid, index_to_world: grid.index_to_world(), data: selected };
    let thickness = local_thickness(&mask);
    let complete = mask.map(|m| m as f32);
    let mut priors = Vec::new();
    for t in &cfg.priors {
        let d = match *t {
            PriorThreshold::DiameterMm(d) => d,
            PriorThreshold::LengthPercentile(p) => {
                // Percentile of the vessel volume by local thickness.
                let mut th: Vec<f64> = thickness.iter().copied().filter(|&x| x > 0.0).collect();
                th.sort_by(f64::total_cmp);
                th.get(((p / 100.0) * th.len() as f64) as usize).copied().unwrap_or(f64::INFINITY)
            }
        };
        let data = mask
            .data
            .iter()
            .zip(&thickness)
            .zip(&dropped)
            .map(|((&m, &t), &drop)| (m == 1 && t >= d && !drop) as u8 as f32)
            .collect();
        priors.push((d, Volume { grid, index_to_world: grid.index_to_world(), data }));
    }
    Ok(Rasterised {
        complete,
        priors,
        tree: None,
        source: format!("label volume {}", path.display()),
        warnings: Vec::new(),
    })
}

fn occupancy_volume_mm3(v: &Volume<f32>) -> f64 {
    let h = v.grid.spacing_mm;
    v.data.iter().map(|&x| x as f64).sum::<f64>() * h[0] * h[1] * h[2]
}

/// The anatomy rasterised: the complete occupancy and one prior per threshold.
fn rasterise_anatomy(cfg: &SynthConfig) -> Result<Rasterised> {
    match &cfg.anatomy {
        Anatomy::Procedural(p) => from_tree(
            p.generate()?,
            cfg,
            format!(
                "procedural CCO tree (seed {}, {} terminals, ctadsa {})",
                p.seed,
                p.terminals,
                env!("CARGO_PKG_VERSION")
            ),
            Vec::new(),
        ),
        Anatomy::Swc { path } => {
            let f = read_swc(path)?;
            let warnings = f.warnings.iter().map(|w| format!("{}:{}: {}", path.display(), w.line, w.problem)).collect();
            from_tree(f.tree, cfg, format!("SWC tree {}", path.display()), warnings)
        }
        Anatomy::Labels { path, labels, prior_drop_labels } => from_labels(path, labels, prior_drop_labels, cfg),
    }
}

/// The ground truth (complete mesh, occupancy, tree) and every prior with its missing vessels,
/// written under `out`.
fn write_truth_and_priors(r: &Rasterised, out: &Path) -> Result<WrittenPriors> {
    let grid = r.complete.grid;
    let complete_mesh = extract_isosurface(&r.complete, 0.5);
    if complete_mesh.is_empty() {
        let thickest = r.tree.as_ref().map_or(String::new(), |t| {
            let r = t.nodes.iter().map(|n| n.radius_mm).fold(0.0, f64::max);
            format!(" (thickest vessel radius {r} mm)")
        });
        // A tree in another unit (m, µm) spans far less or far more than a head.
        let unit_hint = r.tree.as_ref().and_then(|t| {
            let (lo, hi) = t.bounds_mm()?;
            let span = (hi - lo).length();
            (!(10.0..=1000.0).contains(&span)).then(|| {
                format!(
                    "; the tree spans {span:.4} mm where a cerebral tree spans 50–300 mm: are its coordinates in mm?"
                )
            })
        });
        let voxel = grid.spacing_mm[0];
        return Err(CoreError::invalid(format!(
            "the anatomy produced no surface at {voxel} mm voxels{thickest}: its vessels are thinner than a \
             voxel; set a smaller voxel size{}",
            unit_hint.unwrap_or_default()
        )));
    }
    write_mesh(&out.join("gt/complete.obj"), &complete_mesh)?;
    write_nifti(&out.join("gt/occupancy.nii.gz"), &r.complete, "ctadsa vessel occupancy")?;
    if let Some(tree) = &r.tree {
        write_swc(&out.join("gt/tree.swc"), tree, "ctadsa: centred (and transformed) tree, mm")?;
    }
    let mut prior_entries = Vec::new();
    let mut first_meshes: Option<(TriMesh, TriMesh)> = None;
    for (d, prior) in &r.priors {
        let tag = format!("d{:.2}mm", d).replace('.', "p");
        let prior_mesh = extract_isosurface(prior, 0.5);
        let missing = Volume {
            grid,
            index_to_world: r.complete.index_to_world,
            data: r.complete.data.iter().zip(&prior.data).map(|(&c, &p)| (c - p).max(0.0)).collect(),
        };
        let missing_mesh = extract_isosurface(&missing, 0.5);
        write_mesh(&out.join(format!("priors/{tag}/prior.obj")), &prior_mesh)?;
        write_mesh(&out.join(format!("priors/{tag}/missing.obj")), &missing_mesh)?;
        prior_entries.push((*d, tag));
        if first_meshes.is_none() {
            first_meshes = Some((prior_mesh, missing_mesh));
        }
    }
    let (prior_mesh, missing_mesh) =
        first_meshes.ok_or_else(|| CoreError::invalid("at least one prior threshold is needed"))?;
    Ok(WrittenPriors { entries: prior_entries, prior_mesh, missing_mesh })
}

/// The priors written by [`write_truth_and_priors`].
struct WrittenPriors {
    /// (diameter threshold in mm, folder tag under `priors/`) of each prior.
    entries: Vec<(f64, String)>,
    /// The first prior's mesh and its missing vessels.
    prior_mesh: TriMesh,
    missing_mesh: TriMesh,
}

/// The simulated acquisition: view names and geometries, the views as imaged (with the pose
/// errors when set), the images (noise applied, normalised when asked) and the pose errors.
struct Acquisition {
    names: Vec<String>,
    geometries: Vec<TigreGeometry>,
    images: Vec<Vec<f32>>,
    normalised_by: Option<f64>,
    view_corrections: Option<Vec<PoseCorrection>>,
    /// Views that see only part of the vessels.
    warnings: Vec<String>,
    /// The views as imaged (pose errors applied).
    imaged: Vec<ConeBeamView>,
    /// Per view, the arrival map of a time-resolved run ([`SynthConfig::arrival`]).
    arrivals: Option<Vec<Image>>,
}

fn acquire(cfg: &SynthConfig, complete: &Volume<f32>) -> Result<Acquisition> {
    let angles = view_preset(&cfg.views)?;
    let geometries: Vec<TigreGeometry> = angles
        .iter()
        .map(|(_, p, s)| {
            let mut g = cfg.geometry.geometry(*p, *s, 1);
            if let Some(n) = cfg.detector_px {
                g.detector_px = [n, n];
            }
            let b = cfg.binning.max(1);
            g.detector_px = g.detector_px.map(|d| (d / b).max(1));
            g.pixel_mm = g.pixel_mm.map(|p| p * b as f64);
            g
        })
        .collect();
    let views: Vec<ConeBeamView> =
        geometries.iter().map(ConeBeamView::from_tigre).collect::<std::result::Result<_, _>>()?;
    let contrast = complete.map(|v| v * cfg.contrast_per_mm as f32);
    let view_corrections: Option<Vec<PoseCorrection>> = cfg.pose_error.map(|e| {
        let mut rng = ChaCha8Rng::seed_from_u64(e.seed ^ 0x9053);
        (0..views.len())
            .map(|i| if i == 0 { [0.0; 6] } else { random_correction(e.translation_mm, e.rotation_deg, &mut rng) })
            .collect()
    });
    let imaged: Vec<ConeBeamView> = match &view_corrections {
        None => views,
        Some(c) => views.iter().zip(c).map(|(v, c)| corrected_view(v, c)).collect::<std::result::Result<_, _>>()?,
    };
    let mut warnings = Vec::new();
    for (name, view) in angles.iter().map(|(name, _, _)| name).zip(&imaged) {
        // An empty volume is named by the meshes' own check.
        let Some(on) = share_on_detector(complete, view) else { continue };
        if on <= 0.0 {
            return Err(CoreError::invalid(format!(
                "view `{name}`: no vessel projects onto its detector (the tree lies outside the view's field of view; \
                 check --translate-mm, --pose-error-mm, --views and the detector size)"
            )));
        }
        if on < 0.999 {
            warnings.push(format!(
                "view `{name}`: {:.1} % of the vessel volume projects outside the detector (cut off in this view)",
                100.0 * (1.0 - on)
            ));
        }
    }
    let mut images = project_volume(&contrast, &imaged);
    for (i, img) in images.iter_mut().enumerate() {
        cfg.noise.apply(img, i as u64);
    }
    let max = images.iter().flat_map(|i| i.iter()).copied().fold(0.0f32, f32::max);
    let normalised_by = (cfg.normalise && max > 0.0).then_some(max as f64);
    if let Some(m) = normalised_by {
        images.iter_mut().for_each(|img| img.iter_mut().for_each(|v| *v /= m as f32));
    }
    let names = angles.into_iter().map(|(name, _, _)| name).collect();
    Ok(Acquisition { names, geometries, images, normalised_by, view_corrections, warnings, imaged, arrivals: None })
}

/// The share (0–1) of `occupancy`'s total that projects onto `view`'s detector, each voxel
/// counted at its centre; `None` when the volume is empty.
fn share_on_detector(occupancy: &Volume<f32>, view: &ConeBeamView) -> Option<f64> {
    let (w, h) = (view.width() as f64, view.height() as f64);
    let [nx, ny, nz] = occupancy.grid.dims;
    let (mut on, mut total) = (0.0f64, 0.0f64);
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let v = occupancy.get(i, j, k) as f64;
                if v <= 0.0 {
                    continue;
                }
                total += v;
                let p = occupancy.index_to_world.transform_point3(DVec3::new(i as f64, j as f64, k as f64));
                if view.project(p).is_some_and(|uv| (0.0..w).contains(&uv.x) && (0.0..h).contains(&uv.y)) {
                    on += v;
                }
            }
        }
    }
    (total > 0.0).then(|| on / total)
}

/// Writes every view (TIFF, 16-bit PNG, preview) and the pictures; returns the case's entries.
fn write_views(out: &Path, acq: Acquisition, prior_mesh: &TriMesh, missing_mesh: &TriMesh) -> Result<Vec<ViewEntry>> {
    let mut entries = Vec::new();
    let display_max = acq.images.iter().flat_map(|i| i.iter()).copied().fold(0.0f32, f32::max);
    let mut strip: Vec<Image> = Vec::new();
    for (i, ((name, geom), data)) in acq.names.iter().zip(&acq.geometries).zip(acq.images).enumerate() {
        let img = Image { width: geom.detector_px[0], height: geom.detector_px[1], data };
        let arrival = match acq.arrivals.as_ref().map(|maps| &maps[i]) {
            Some(map) => {
                let relative = format!("views/{name}-arrival.tiff");
                write_tiff_f32(&out.join(&relative), map)?;
                Some(relative)
            }
            None => None,
        };
        write_tiff_f32(&out.join(format!("views/{name}.tiff")), &img)?;
        let scale = write_png16(&out.join(format!("views/{name}.png")), &img)?;
        write_preview_png(&out.join(format!("pictures/view-{name}.png")), &img, 0.0, display_max, true)?;
        entries.push(ViewEntry {
            name: name.clone(),
            image: format!("views/{name}.tiff"),
            png_scale: Some(scale),
            preview_png: Some(format!("views/{name}.png")),
            geometry: ViewGeometry::from_tigre(geom),
            arrival,
        });
        strip.push(img);
    }
    write_view_strip(&out.join("pictures/views.png"), &strip, display_max)?;
    write_mesh_png(
        &out.join("pictures/meshes.png"),
        &[Coloured { mesh: prior_mesh, rgb: [200, 60, 50] }, Coloured { mesh: missing_mesh, rgb: [50, 110, 220] }],
        &standard_views(360),
    )?;
    Ok(entries)
}

/// What [`synthesize`] writes into a case folder (besides `.tmp` files while it writes).
pub const CASE_OUTPUTS: [&str; 6] = [CASE_FILE, "PROVENANCE.md", "views", "priors", "gt", "pictures"];

/// Removes an earlier case from `dir` — [`CASE_OUTPUTS`] and nothing else the folder holds — so
/// that a case made again there keeps no prior, view or picture of the old one.
fn remove_case(dir: &Path) -> Result<()> {
    CASE_OUTPUTS.iter().try_for_each(|name| remove_path(&dir.join(name)))
}

/// Writes a synthetic case into `out`, reporting each step to `progress`. Files of an earlier
/// case there are overwritten, not removed ([`synthesize_replacing`] replaces one).
pub fn synthesize(cfg: &SynthConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<SynthSummary> {
    synthesize_into(cfg, out, false, progress)
}

/// [`synthesize`], replacing an earlier case in `out`: once the new case's anatomy and views
/// have passed their checks (a refused case leaves the old one as it was), the old case's files
/// ([`CASE_OUTPUTS`], nothing else) are removed, so that no prior, view or picture of it remains.
pub fn synthesize_replacing(cfg: &SynthConfig, out: &Path, progress: &mut dyn FnMut(&str)) -> Result<SynthSummary> {
    synthesize_into(cfg, out, true, progress)
}

fn synthesize_into(
    cfg: &SynthConfig,
    out: &Path,
    replace: bool,
    progress: &mut dyn FnMut(&str),
) -> Result<SynthSummary> {
    if cfg.priors.is_empty() {
        return Err(CoreError::invalid("at least one prior threshold is needed"));
    }
    cfg.validate()?;
    progress("anatomy");
    let r = rasterise_anatomy(cfg)?;
    let grid = r.complete.grid;
    progress("projections");
    let mut acq = acquire(cfg, &r.complete)?;
    let (normalised_by, view_corrections, n_views) = (acq.normalised_by, acq.view_corrections.clone(), acq.names.len());
    let view_warnings = std::mem::take(&mut acq.warnings);
    if let Some(spec) = &cfg.arrival {
        let tree = r.tree.as_ref().ok_or_else(|| CoreError::invalid("arrival maps need a tree"))?;
        acq.arrivals = Some(acq.imaged.iter().map(|view| arrival_map(tree, view, spec)).collect());
    }
    if replace {
        remove_case(out)?;
    }
    progress("meshes");
    let WrittenPriors { entries: prior_entries, prior_mesh, missing_mesh } = write_truth_and_priors(&r, out)?;
    progress("files");
    let entries = write_views(out, acq, &prior_mesh, &missing_mesh)?;
    let (d0, tag0) = &prior_entries[0];
    let bounds = grid.bounds();
    let case = CaseFile {
        format: CASE_FORMAT.into(),
        version: CASE_VERSION,
        name: cfg.name.clone(),
        provenance: Provenance {
            source: r.source.clone(),
            generator: format!(
                "ctadsa synth {} ({})",
                env!("CARGO_PKG_VERSION"),
                serde_json::to_string(cfg).unwrap_or_default()
            ),
            notes: provenance_notes(&cfg.anatomy),
        },
        image_values: ImageValues {
            units: "contrast × mm (line integral of the vessel occupancy × contrast_per_mm)".into(),
            normalised_by,
            contrast_per_mm: Some(cfg.contrast_per_mm),
        },
        volume: VolumeEntry {
            min_mm: bounds.min_mm,
            max_mm: bounds.max_mm,
            voxel_mm: grid.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min),
        },
        views: entries,
        prior: Some(PriorEntry {
            mesh: format!("priors/{tag0}/prior.obj"),
            description: match &cfg.anatomy {
                Anatomy::Labels { prior_drop_labels, .. } if !prior_drop_labels.is_empty() => {
                    format!("vessels with diameter ≥ {d0:.2} mm, without labels {prior_drop_labels:?}")
                }
                _ => format!("vessels with diameter ≥ {d0:.2} mm"),
            },
            threshold_mm: Some(*d0),
        }),
        ground_truth: Some(GroundTruth {
            complete_mesh: "gt/complete.obj".into(),
            missing_mesh: Some(format!("priors/{tag0}/missing.obj")),
            labels: Some("gt/occupancy.nii.gz".into()),
            tree: r.tree.as_ref().map(|_| "gt/tree.swc".into()),
            view_corrections,
        }),
    };
    case.save(out)?;
    write_file(&out.join("PROVENANCE.md"), provenance_markdown(&case).as_bytes())?;
    Ok(SynthSummary {
        dir: out.to_path_buf(),
        voxels: grid.dims,
        voxel_mm: grid.spacing_mm,
        views: n_views,
        prior_thresholds_mm: prior_entries.iter().map(|p| p.0).collect(),
        complete_volume_mm3: occupancy_volume_mm3(&r.complete),
        prior_volume_mm3: occupancy_volume_mm3(&r.priors[0].1),
        warnings: r.warnings.into_iter().chain(view_warnings).collect(),
    })
}

/// Side-by-side 8-bit previews of the views (inverted, common scale).
fn write_view_strip(path: &Path, images: &[Image], max: f32) -> Result<()> {
    let h = images.iter().map(|i| i.height).max().unwrap_or(1);
    let w: u32 = images.iter().map(|i| i.width).sum();
    let mut px = vec![255u8; (w * h) as usize];
    let mut x0 = 0usize;
    for img in images {
        for r in 0..img.height as usize {
            for c in 0..img.width as usize {
                let t = (img.data[r * img.width as usize + c] / max.max(1e-12)).clamp(0.0, 1.0);
                px[r * w as usize + x0 + c] = (255.0 * (1.0 - t)).round() as u8;
            }
        }
        x0 += img.width as usize;
    }
    write_rgb_or_grey(path, w, h, px, 1)
}

fn provenance_notes(anatomy: &Anatomy) -> Vec<String> {
    let name = match anatomy {
        Anatomy::Swc { path } | Anatomy::Labels { path, .. } => {
            path.file_name().map(|f| f.to_string_lossy().to_string()).unwrap_or_default()
        }
        Anatomy::Procedural(_) => return vec!["Synthetic anatomy generated by ctadsa; no third-party data.".into()],
    };
    if name.ends_with(".swc") {
        vec![
            "BraVa database (Brain Vasculature): Wright, S. N. et al., \"Digital reconstruction and morphometric \
             analysis of human brain arterial vasculature from magnetic resonance angiography\", NeuroImage 82 \
             (2013) 170-181; distributed through NeuroMorpho.Org."
                .into(),
            "Copied unchanged from GitHub aditeyapandey/3DArteryVisualization, commit \
             2500d92958b861215e58fe5661c55e9bc153cb74, folder swc_files/."
                .into(),
            format!("Tree file: {name}; centred on the isocentre (and transformed as the generator line says)."),
        ]
    } else {
        vec![
            "TopCoW challenge: Yang, K. et al., \"TopCoW: Benchmarking Topology-Aware Anatomical Segmentation of \
             the Circle of Willis for CTA and MRA\", arXiv 2312.17670. Research use."
                .into(),
            "Copied unchanged from GitHub CoWBenchmark/TopCoW_Eval_Metrics, commit \
             25ca8399e056e71e3ff6743ac4a47ce28624cb3d, folder test_assets/seg_metrics/topcow_roi/."
                .into(),
            format!("Label volume: {name}; direction matrix ignored, centred on the isocentre."),
        ]
    }
}

fn provenance_markdown(case: &CaseFile) -> String {
    let mut s = format!(
        "# Provenance of case `{}`\n\nSource: {}\n\nGenerator: {}\n\n",
        case.name, case.provenance.source, case.provenance.generator
    );
    for n in &case.provenance.notes {
        s.push_str(&format!("- {n}\n"));
    }
    s
}
