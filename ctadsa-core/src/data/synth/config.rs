//! What `ctadsa synth` is asked for: the anatomy, its pose, the views, noise, priors and
//! simulated pose errors and arrival maps; their checks and the built-in cases.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::arrival::ArrivalSpec;
use super::presets::GeometryPreset;
use crate::data::projector::noise::NoiseModel;
use crate::data::tree::prior::PriorThreshold;
use crate::data::tree::procedural::ProceduralTree;
use crate::error::{CoreError, Result};

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
    /// A time-resolved run: each view also gets an arrival map ([`super::arrival::arrival_map`]; trees
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
