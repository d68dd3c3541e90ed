//! `ctadsa synth`: make case folders.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use ctadsa_core::data::case::CASE_FILE;
use ctadsa_core::data::projector::noise::NoiseModel;
use ctadsa_core::data::synth::arrival::ArrivalSpec;
use ctadsa_core::data::synth::presets::GeometryPreset;
use ctadsa_core::data::synth::{Anatomy, PoseErrorSpec, SynthConfig, synthesize_replacing};
use ctadsa_core::data::tree::prior::PriorThreshold;
use ctadsa_core::data::tree::procedural::ProceduralTree;

use crate::progress::bar;

#[derive(Args)]
pub struct SynthArgs {
    /// Output folder (one case), or parent folder with --all-swc.
    #[arg(long)]
    out: PathBuf,
    /// A vessel tree (SWC). Default: the built-in procedural tree.
    #[arg(long, conflicts_with_all = ["labels", "all_swc"])]
    tree: Option<PathBuf>,
    /// Every `*.swc` in this folder, one case each (named after the file).
    #[arg(long, conflicts_with = "labels")]
    all_swc: Option<PathBuf>,
    /// A label volume (NIfTI) instead of a tree.
    #[arg(long)]
    labels: Option<PathBuf>,
    /// Label values to use from --labels (comma-separated; default: every non-zero label).
    #[arg(long, value_delimiter = ',')]
    label_ids: Vec<u32>,
    /// Label values from --labels to leave out of the prior whatever their thickness (whole
    /// branches missing from the prior, e.g. TopCoW's communicating arteries 8,9,10).
    #[arg(long, value_delimiter = ',', requires = "labels")]
    prior_drop_labels: Vec<u32>,
    /// Seed of the procedural tree.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Terminal segments of the procedural tree.
    #[arg(long, default_value_t = 120)]
    terminals: usize,
    /// Views: ap-lat, ap-lat-oblique, or angles:P[/S],… (degrees).
    #[arg(long, default_value = "ap-lat-oblique")]
    views: String,
    /// Geometry preset: reference (DSD 700, DSO 500, 512², 0.5 mm) or c-arm (1200, 800, 1024², 0.2 mm).
    #[arg(long, default_value = "reference")]
    geometry: String,
    /// Detector binning factor.
    #[arg(long, default_value_t = 1)]
    binning: u32,
    /// Detector size in pixels per side (before binning) instead of the preset's, same pitch.
    #[arg(long)]
    detector_px: Option<u32>,
    /// Voxel size (mm); default 256 voxels along the longest side of the tree's box.
    #[arg(long)]
    voxel_mm: Option<f64>,
    /// Prior: keep vessels with diameter ≥ these (mm); the first is the case's prior.
    #[arg(long, value_delimiter = ',', default_values_t = vec![1.5])]
    prior_diameter: Vec<f64>,
    /// Prior by length percentile instead (drop the thinnest P% of centreline length).
    #[arg(long, value_delimiter = ',', conflicts_with = "prior_diameter")]
    prior_percentile: Vec<f64>,
    /// Rotation (degrees about x, y, z) after centring.
    #[arg(long, value_delimiter = ',', num_args = 3, allow_hyphen_values = true)]
    rotate_deg: Option<Vec<f64>>,
    /// Translation (mm) after the rotation.
    #[arg(long, value_delimiter = ',', num_args = 3, allow_hyphen_values = true)]
    translate_mm: Option<Vec<f64>>,
    /// DSA value per mm of vessel.
    #[arg(long, default_value_t = 1.0)]
    contrast: f64,
    /// Poisson noise: unattenuated photons per pixel.
    #[arg(long)]
    noise_photons: Option<f64>,
    /// With --noise-photons: attenuation per image unit (1 / (contrast × mm)); a pixel of value
    /// `p` is seen through `photons × e^(−μ p)` photons, so the background's noise is
    /// 1 / (μ √photons) image units and a vessel's e^(μ p / 2) times that (default 1).
    #[arg(long, requires = "noise_photons")]
    noise_attenuation: Option<f64>,
    /// Gaussian noise standard deviation (image units).
    #[arg(long)]
    noise_sigma: Option<f64>,
    /// Divide images by their maximum over all views (recorded in the case).
    #[arg(long)]
    normalise: bool,
    /// Sub-samples per voxel edge for vessel occupancy.
    #[arg(long, default_value_t = 2)]
    supersample: usize,
    /// Simulated registration error: image every view but the first with its pose moved by
    /// this translation (mm, random direction) while the case keeps the nominal pose.
    #[arg(long, default_value_t = 0.0)]
    pose_error_mm: f64,
    /// Simulated registration error: rotation (degrees, random axis through the isocentre).
    #[arg(long, default_value_t = 0.0)]
    pose_error_deg: f64,
    /// A time-resolved run at this many frames per second: each view also gets an arrival map
    /// (`views/<name>-arrival.tiff`: per pixel, the frame at which contrast first fills a vessel
    /// along its ray; trees only). Neuro DSA runs at 2–7.5 frames/s.
    #[arg(long)]
    arrival_fps: Option<f64>,
    /// With --arrival-fps: the contrast's velocity along the vessels (mm/s).
    #[arg(long, default_value_t = 300.0, requires = "arrival_fps")]
    flow_mm_s: f64,
    /// With --arrival-fps: how much the velocity differs between vessels, each segment's
    /// --flow-mm-s × e^(σ N(0,1)) with σ this (0: one velocity everywhere).
    #[arg(long, default_value_t = 0.0, requires = "arrival_fps")]
    arrival_velocity_spread: f64,
    /// With --arrival-fps: error of each pixel's detected frame, N(0, σ²) frames with σ this,
    /// rounded (0: exact).
    #[arg(long, default_value_t = 0.0, requires = "arrival_fps")]
    arrival_frame_noise: f64,
    /// With --arrival-fps: the lateral plane's frames this many frames after the frontal's (a
    /// biplane system images its planes alternately: 0.5); 0: at the same instants.
    #[arg(long, default_value_t = 0.0, requires = "arrival_fps")]
    arrival_interleave: f64,
    /// With --arrival-fps: seed of the velocities' and the frame errors' draws.
    #[arg(long, default_value_t = 0, requires = "arrival_fps")]
    arrival_seed: u64,
    /// Replace a case already in the output folder: its case.json, views, priors, ground truth,
    /// pictures and PROVENANCE.md go first (other files stay).
    #[arg(long)]
    overwrite: bool,
}

fn three(v: &Option<Vec<f64>>, what: &str) -> Result<[f64; 3]> {
    match v {
        None => Ok([0.0; 3]),
        Some(v) if v.len() == 3 => Ok([v[0], v[1], v[2]]),
        Some(v) => bail!("{what} needs 3 values, got {}", v.len()),
    }
}

pub fn config_from(args: &SynthArgs, anatomy: Anatomy, name: String) -> Result<SynthConfig> {
    let priors = if args.prior_percentile.is_empty() {
        args.prior_diameter.iter().map(|&d| PriorThreshold::DiameterMm(d)).collect()
    } else {
        args.prior_percentile.iter().map(|&p| PriorThreshold::LengthPercentile(p)).collect()
    };
    Ok(SynthConfig {
        name,
        anatomy,
        rotation_deg: three(&args.rotate_deg, "--rotate-deg")?,
        translation_mm: three(&args.translate_mm, "--translate-mm")?,
        voxel_mm: args.voxel_mm,
        supersample: args.supersample,
        views: args.views.clone(),
        geometry: GeometryPreset::parse(&args.geometry)?,
        binning: args.binning,
        detector_px: args.detector_px,
        contrast_per_mm: args.contrast,
        noise: NoiseModel {
            poisson_photons: args.noise_photons,
            attenuation: args.noise_attenuation,
            gaussian_sigma: args.noise_sigma,
            ..Default::default()
        },
        normalise: args.normalise,
        priors,
        pose_error: (args.pose_error_mm != 0.0 || args.pose_error_deg != 0.0).then_some(PoseErrorSpec {
            translation_mm: args.pose_error_mm,
            rotation_deg: args.pose_error_deg,
            seed: args.seed,
        }),
        arrival: args.arrival_fps.map(|frames_per_s| ArrivalSpec {
            velocity_spread: args.arrival_velocity_spread,
            frame_noise: args.arrival_frame_noise,
            interleave_frames: args.arrival_interleave,
            seed: args.arrival_seed,
            ..ArrivalSpec::ideal(frames_per_s, args.flow_mm_s)
        }),
    })
}

pub fn run(args: SynthArgs) -> Result<()> {
    let mut jobs: Vec<(Anatomy, String, PathBuf)> = Vec::new();
    if let Some(dir) = &args.all_swc {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("cannot list {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("swc")))
            .collect();
        files.sort();
        if files.is_empty() {
            bail!("no .swc file in {}", dir.display());
        }
        for f in files {
            let stem = f
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("tree")
                .split('.')
                .next()
                .unwrap_or("tree")
                .to_string();
            if let Some((_, _, earlier)) = jobs.iter().find(|(_, name, _)| *name == stem) {
                bail!(
                    "{} and another tree in {} both map to the case folder {} (named up to the first `.`); \
                     rename one",
                    f.display(),
                    dir.display(),
                    earlier.display()
                );
            }
            jobs.push((Anatomy::Swc { path: f }, stem.clone(), args.out.join(stem)));
        }
    } else if let Some(t) = &args.tree {
        let stem = t.file_stem().and_then(|s| s.to_str()).unwrap_or("tree").to_string();
        jobs.push((Anatomy::Swc { path: t.clone() }, stem, args.out.clone()));
    } else if let Some(l) = &args.labels {
        let stem = l
            .file_name()
            .and_then(|s| s.to_str())
            .unwrap_or("labels")
            .split('.')
            .next()
            .unwrap_or("labels")
            .to_string();
        jobs.push((
            Anatomy::Labels {
                path: l.clone(),
                labels: args.label_ids.clone(),
                prior_drop_labels: args.prior_drop_labels.clone(),
            },
            stem,
            args.out.clone(),
        ));
    } else {
        let max = ctadsa_core::data::tree::procedural::MAX_TERMINALS;
        if !(1..=max).contains(&args.terminals) {
            anyhow::bail!("--terminals {}: the procedural tree takes 1 to {max} terminals", args.terminals);
        }
        let p = ProceduralTree { seed: args.seed, terminals: args.terminals, ..Default::default() };
        jobs.push((Anatomy::Procedural(p), format!("procedural-seed{}", args.seed), args.out.clone()));
    }
    // Every folder is checked before any case is made: a case there is kept unless asked.
    for (_, _, out) in &jobs {
        if out.join(CASE_FILE).exists() && !args.overwrite {
            bail!(
                "{} already holds a case: pass --overwrite to replace it (its views, priors, ground truth and \
                 pictures go; other files stay)",
                out.display()
            );
        }
    }
    let steps = ["anatomy", "projections", "meshes", "files"];
    let pb = bar((jobs.len() * steps.len()) as u64, "synth");
    for (anatomy, name, out) in jobs {
        let cfg = config_from(&args, anatomy, name.clone())?;
        let summary = synthesize_replacing(&cfg, &out, &mut |step| {
            pb.set_message(format!("{name}: {step}"));
            pb.inc(1);
        })
        .with_context(|| format!("synthesising case `{name}`"))?;
        for w in &summary.warnings {
            pb.suspend(|| println!("warning: {w}"));
        }
        pb.suspend(|| println!(
            "{name}: {} views, {:?} voxels of {:.3} mm, vessel volume {:.0} mm³ (prior {:.0} mm³ at ≥ {:.2} mm) → {}",
            summary.views,
            summary.voxels,
            summary.voxel_mm[0],
            summary.complete_volume_mm3,
            summary.prior_volume_mm3,
            summary.prior_thresholds_mm[0],
            summary.dir.display()
        ));
        if let Some(a) = &cfg.arrival {
            let mut real = String::new();
            if a.velocity_spread > 0.0 {
                real += &format!(", velocity spread σ {}", a.velocity_spread);
            }
            if a.frame_noise > 0.0 {
                real += &format!(", frame error σ {} frames", a.frame_noise);
            }
            if a.interleave_frames > 0.0 {
                real += &format!(", lateral frames {} frame late", a.interleave_frames);
            }
            pb.suspend(|| {
                println!(
                    "{name}: arrival maps of a run at {} frames/s, contrast at {} mm/s{real} (views/<view>-arrival.tiff)",
                    a.frames_per_s, a.flow_mm_s
                )
            });
        }
    }
    pb.finish_with_message("done");
    Ok(())
}
