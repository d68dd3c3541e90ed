//! `ctadsa import-dsa` (DICOM runs + a prior → a case) and `ctadsa prior` (CTA labels → prior).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::Args;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::case::prior_check::check_prior_in_views;
use ctadsa_core::data::clinical::dsa::Subtraction;
use ctadsa_core::data::clinical::import::{DsaOptions, DsaView, dsa_view, view_name, write_dsa_case};
use ctadsa_core::data::clinical::prior::{LabelPriorOptions, Visibility, centred_prior_from_labels, prior_from_labels};
use ctadsa_core::data::clinical::simulate::simulated_case_runs;
use ctadsa_core::data::clinical::xa::{read_xa_run, write_xa_run};
use ctadsa_core::data::mesh::TriMesh;
use ctadsa_core::data::mesh::io::{MeshFormat, read_mesh, write_mesh};
use ctadsa_render::ConeBeamView;

/// Options shared by both commands for making the prior from a label volume.
#[derive(Args, Clone)]
pub struct LabelArgs {
    /// Label values making the vessels (comma-separated; default: every non-zero label).
    #[arg(long, value_delimiter = ',')]
    label_ids: Vec<u32>,
    /// Drop connected pieces of the prior surface smaller than this (mm²) [default: 20].
    #[arg(long, value_parser = island_area)]
    min_island_mm2: Option<f64>,
    /// Shift (mm) added to the label volume's world coordinates, e.g. minus the isocentre's
    /// position in CTA coordinates from a registration.
    #[arg(long, value_delimiter = ',', num_args = 3, allow_hyphen_values = true)]
    prior_shift_mm: Option<Vec<f64>>,
    /// Put the centre of the prior's box at the isocentre (a rough start for pose refinement).
    #[arg(long, conflicts_with = "prior_shift_mm")]
    centre_prior: bool,
    /// Keep only the part of the prior the views see: all (no cut), every, or any [default:
    /// every].
    #[arg(long, value_parser = ["all", "every", "any"])]
    visible: Option<String>,
}

/// Islands smaller than this (mm²) are dropped from a label prior unless `--min-island-mm2`
/// says otherwise.
const DEFAULT_MIN_ISLAND_MM2: f64 = 20.0;

impl LabelArgs {
    /// The first of these options given on the command line, if any: they shape a prior made
    /// from a label volume and mean nothing without one.
    fn first_given(&self) -> Option<&'static str> {
        [
            (!self.label_ids.is_empty(), "--label-ids"),
            (self.min_island_mm2.is_some(), "--min-island-mm2"),
            (self.prior_shift_mm.is_some(), "--prior-shift-mm"),
            (self.centre_prior, "--centre-prior"),
            (self.visible.is_some(), "--visible"),
        ]
        .into_iter()
        .find_map(|(given, flag)| given.then_some(flag))
    }
}

/// `--min-island-mm2`: a finite area of at least 0 mm².
fn island_area(text: &str) -> std::result::Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        Ok(v) => Err(format!("{v} is not an area: expected a finite number ≥ 0 (mm²)")),
        Err(e) => Err(e.to_string()),
    }
}

fn visibility(text: &str) -> Result<Visibility> {
    Ok(match text {
        "all" => Visibility::All,
        "every" => Visibility::SeenByEveryView,
        "any" => Visibility::SeenByAnyView,
        other => bail!("--visible `{other}`: expected all, every or any"),
    })
}

/// The largest shift (mm) `--prior-shift-mm` takes per axis: 10 m, far past any registration
/// of a head CTA to a C-arm's isocentre.
const MAX_PRIOR_SHIFT_MM: f64 = 10_000.0;

/// Builds the prior mesh from a label volume as the options say.
fn label_prior(labels: &Path, a: &LabelArgs, views: &[ConeBeamView]) -> Result<(TriMesh, String)> {
    let shift = match &a.prior_shift_mm {
        Some(v) if v.len() == 3 && v.iter().any(|s| s.is_nan() || s.abs() > MAX_PRIOR_SHIFT_MM) => {
            bail!("--prior-shift-mm {v:?}: each component must be within ±{MAX_PRIOR_SHIFT_MM} mm")
        }
        Some(v) if v.len() == 3 => [v[0], v[1], v[2]],
        Some(v) => bail!("--prior-shift-mm needs 3 values, got {}", v.len()),
        None => [0.0; 3],
    };
    let min_island_mm2 = a.min_island_mm2.unwrap_or(DEFAULT_MIN_ISLAND_MM2);
    let o = LabelPriorOptions { labels: a.label_ids.clone(), min_island_mm2, translation_mm: shift };
    let visible_name = a.visible.as_deref().unwrap_or("every");
    let visible = visibility(visible_name)?;
    let (p, shift) = if a.centre_prior {
        centred_prior_from_labels(labels, &o, views, visible)?
    } else {
        (prior_from_labels(labels, &o, views, visible)?, shift)
    };
    eprintln!(
        "prior from {}: {} voxels, {} triangles, {} islands < {} mm² dropped, {} triangles not visible; shift {:?} mm",
        labels.display(),
        p.voxels,
        p.mesh.faces.len(),
        p.islands_dropped,
        min_island_mm2,
        p.hidden_triangles,
        shift
    );
    let description = format!(
        "labels {:?} of {} (islands < {} mm² dropped, visibility `{}`, shift {:?} mm)",
        a.label_ids,
        labels.display(),
        min_island_mm2,
        visible_name,
        shift
    );
    Ok((p.mesh, description))
}

#[derive(Args)]
pub struct ImportDsaArgs {
    /// A DSA run (multi-frame XA DICOM, uncompressed); once per view.
    #[arg(long = "run", required = true)]
    runs: Vec<PathBuf>,
    /// Output case folder.
    #[arg(long)]
    out: PathBuf,
    /// Subtraction: log (ln mask − ln fill), linear (mask − fill) or none (already subtracted).
    #[arg(long, default_value = "log")]
    subtraction: String,
    /// Mask frames (0-based, comma-separated); default: the file's Mask Subtraction Sequence,
    /// else frame 0.
    #[arg(long, value_delimiter = ',')]
    mask_frames: Vec<usize>,
    /// MIP frame range `A-B` (0-based, inclusive); default: chosen from the contrast curve.
    #[arg(long)]
    frames: Option<String>,
    /// With automatic frames, keep frames with at least this fraction of the peak contrast.
    #[arg(long, default_value_t = 0.5)]
    curve_fraction: f64,
    /// Detector binning.
    #[arg(long, default_value_t = 1)]
    binning: u32,
    /// Mirror the images left-right (on top of what Patient Orientation implies).
    #[arg(long)]
    flip_horizontal: bool,
    /// Mirror the images top-bottom.
    #[arg(long)]
    flip_vertical: bool,
    /// Also write each view's arrival map (per pixel, the frame its contrast arrives; frames of
    /// the runs must be simultaneous, as a biplane system's are): 2-view runs use them to leave
    /// ghosts out of the centreline (docs/DATA.md).
    #[arg(long)]
    arrival: bool,
    /// Prior surface mesh (OBJ/PLY/STL) already in the C-arm frame (mm, isocentre at 0).
    #[arg(long, conflicts_with = "labels")]
    prior: Option<PathBuf>,
    /// CTA label volume (NIfTI) to make the prior from.
    #[arg(long)]
    labels: Option<PathBuf>,
    #[command(flatten)]
    label_args: LabelArgs,
    /// Margin (mm) around the prior for the working volume.
    #[arg(long, default_value_t = 10.0)]
    margin_mm: f64,
    /// Working voxel (mm).
    #[arg(long, default_value_t = 0.4)]
    voxel_mm: f64,
}

fn parse_range(text: &str) -> Result<std::ops::RangeInclusive<usize>> {
    let (a, b) = text.split_once('-').with_context(|| format!("--frames `{text}`: expected A-B"))?;
    let (a, b): (usize, usize) =
        (a.trim().parse().context("--frames start")?, b.trim().parse().context("--frames end")?);
    anyhow::ensure!(a <= b, "--frames `{text}`: start after end");
    Ok(a..=b)
}

pub fn import_dsa(args: ImportDsaArgs) -> Result<()> {
    if let (None, Some(flag)) = (&args.labels, args.label_args.first_given()) {
        bail!(
            "{flag} shapes a prior made from --labels; a --prior mesh is taken as it is, so drop {flag} or give --labels"
        );
    }
    let options = DsaOptions {
        subtraction: Subtraction::parse(&args.subtraction)?,
        mask_frames: (!args.mask_frames.is_empty()).then(|| args.mask_frames.clone()),
        frames: args.frames.as_deref().map(parse_range).transpose()?,
        curve_fraction: args.curve_fraction,
        binning: args.binning,
        flip_horizontal: args.flip_horizontal,
        flip_vertical: args.flip_vertical,
        arrival: args.arrival,
    };
    let mut views: Vec<DsaView> = Vec::new();
    for (i, path) in args.runs.iter().enumerate() {
        let run = read_xa_run(path)?;
        let v = dsa_view(&run, &view_name(i, path), &options)?;
        eprintln!(
            "{}: {} frames of {} × {} px, primary {:.1}°, secondary {:.1}°, DSD {} mm, DSO {} mm; masks {:?}, MIP {}–{}",
            path.display(),
            run.frames.len(),
            run.columns,
            run.rows,
            run.geometry.primary_deg,
            run.geometry.secondary_deg,
            run.geometry.dsd_mm,
            run.geometry.dso_mm,
            v.mask_frames,
            v.frames.start(),
            v.frames.end()
        );
        views.push(v);
    }
    let render_views: Vec<ConeBeamView> =
        views.iter().map(|v| ConeBeamView::from_tigre(&v.geometry)).collect::<Result<_, _>>()?;
    // A prior outside the views' field (another frame, a missing shift) is refused before the
    // case is written.
    let prior = match (&args.prior, &args.labels) {
        (Some(p), _) => {
            let mesh = read_mesh(p)?;
            check_prior_in_views(&mesh, &render_views, p)?;
            Some((mesh, format!("mesh {}", p.display())))
        }
        (None, Some(l)) => {
            let (mesh, description) = label_prior(l, &args.label_args, &render_views)?;
            check_prior_in_views(&mesh, &render_views, l)?;
            Some((mesh, description))
        }
        (None, None) => None,
    };
    if prior.is_none() {
        eprintln!("no prior given (--prior or --labels): the case can only be reconstructed without one");
    }
    let name = args.out.file_name().and_then(|s| s.to_str()).unwrap_or("dsa-case").to_string();
    write_dsa_case(
        &args.out,
        &name,
        &views,
        prior.as_ref().map(|(m, d)| (m, d.clone())),
        args.margin_mm,
        args.voxel_mm,
        vec![],
    )
    .with_context(|| {
        format!("case {} not written (its working volume comes from --margin-mm and --voxel-mm)", args.out.display())
    })?;
    // Read it back: the same checks `complete` will apply (the prior's was made above).
    Case::load(&args.out).with_context(|| format!("the written case {} does not load", args.out.display()))?;
    println!("case written to {}", args.out.display());
    Ok(())
}

#[derive(Args)]
pub struct PriorArgs {
    /// CTA label volume (NIfTI).
    #[arg(long)]
    labels: PathBuf,
    /// Output mesh (OBJ, PLY or STL).
    #[arg(long)]
    out: PathBuf,
    /// A case whose views decide visibility (--visible every|any).
    #[arg(long)]
    case: Option<PathBuf>,
    #[command(flatten)]
    label_args: LabelArgs,
}

pub fn prior(args: PriorArgs) -> Result<()> {
    // Before any work: the mesh format comes from the output's extension.
    MeshFormat::from_path(&args.out)?;
    let views = match &args.case {
        Some(dir) => Case::load(dir)?.views.views().to_vec(),
        None => Vec::new(),
    };
    let mut label_args = args.label_args.clone();
    if views.is_empty() {
        match label_args.visible.as_deref() {
            Some("all") => {}
            Some(cut) => bail!("--visible {cut}: a visibility cut needs the views of a --case"),
            None => {
                eprintln!("no --case: no visibility cut");
                label_args.visible = Some("all".into());
            }
        }
    }
    let (mesh, _) = label_prior(&args.labels, &label_args, &views)?;
    // With --case, a prior the case's views do not see (a missing shift) is refused, as the
    // case would refuse it.
    check_prior_in_views(&mesh, &views, &args.labels)?;
    write_mesh(&args.out, &mesh)?;
    println!("prior mesh written to {} ({} triangles)", args.out.display(), mesh.faces.len());
    Ok(())
}

#[derive(Args)]
pub struct ExportDicomArgs {
    /// A case with TIGRE (angle) geometry, e.g. from `ctadsa synth`.
    #[arg(long)]
    case: PathBuf,
    /// Output folder: one multi-frame XA file per view.
    #[arg(long)]
    out: PathBuf,
    /// Peak attenuation of the contrast (κ × largest line integral).
    #[arg(long, default_value_t = 1.2)]
    peak_attenuation: f32,
    /// Store the frontal (first) run mirrored with Patient Orientation L\F, as displayed to a
    /// viewer facing the patient.
    #[arg(long)]
    mirror_first: bool,
}

/// Writes simulated DSA runs (mask + 7 bolus frames) of a case's views as DICOM.
pub fn export_dicom(args: ExportDicomArgs) -> Result<()> {
    let case = Case::load(&args.case)?;
    for (name, spec) in simulated_case_runs(&case, args.peak_attenuation, args.mirror_first)? {
        let path = args.out.join(format!("{name}.dcm"));
        write_xa_run(&path, &spec)?;
        println!(
            "{}: {} frames, primary {:.1}°, secondary {:.1}°",
            path.display(),
            spec.frames.len(),
            spec.primary_deg.unwrap_or(0.0),
            spec.secondary_deg.unwrap_or(0.0)
        );
    }
    Ok(())
}
