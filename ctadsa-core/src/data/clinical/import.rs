//! DSA runs (DICOM) + a prior → a case folder.

use std::ops::RangeInclusive;
use std::path::Path;

use ctadsa_render::{ConeBeamView, TigreGeometry};
use glam::DVec3;

use super::dsa::{Subtraction, average_frames, choose_frames, contrast_curve, max_intensity_projection, subtract};
use super::timing::{ArrivalClock, arrival_offsets};
use super::xa::XaRun;
use crate::data::case::images::{Image, write_png16, write_tiff_f32};
use crate::data::case::images::{NO_ARRIVAL, bin_arrival, bin_image};
use crate::data::case::{
    CASE_FILE, CASE_FORMAT, CASE_VERSION, CaseFile, ImageValues, PriorEntry, Provenance, ViewEntry, ViewGeometry,
    VolumeEntry,
};
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::write_mesh;
use crate::error::{CoreError, Result};
use crate::stats::percentile;

/// How a run becomes one view image.
#[derive(Debug, Clone, PartialEq)]
pub struct DsaOptions {
    pub subtraction: Subtraction,
    /// Mask frames (0-based); `None`: the file's Mask Subtraction Sequence, else frame 0.
    pub mask_frames: Option<Vec<usize>>,
    /// Frames of the MIP (0-based, inclusive); `None`: chosen from the contrast curve.
    pub frames: Option<RangeInclusive<usize>>,
    /// With automatic frames: keep the frames around the peak with at least this fraction of
    /// the peak contrast.
    pub curve_fraction: f64,
    /// Detector binning.
    pub binning: u32,
    /// Flip columns / rows in addition to what Patient Orientation (0020,0020) implies.
    pub flip_horizontal: bool,
    pub flip_vertical: bool,
    /// Also derive the view's arrival map ([`arrival_from_frames`]) for a time-resolved case.
    pub arrival: bool,
}

impl Default for DsaOptions {
    fn default() -> Self {
        Self {
            subtraction: Subtraction::Log,
            mask_frames: None,
            frames: None,
            curve_fraction: 0.5,
            binning: 1,
            flip_horizontal: false,
            flip_vertical: false,
            arrival: false,
        }
    }
}

/// One view made from a run.
#[derive(Debug, Clone)]
pub struct DsaView {
    pub name: String,
    pub image: Image,
    pub geometry: TigreGeometry,
    pub mask_frames: Vec<usize>,
    pub frames: RangeInclusive<usize>,
    /// Contrast per frame (mean of the brightest 2 % of subtracted pixels).
    pub curve: Vec<f64>,
    /// What was done, for the case's provenance.
    pub notes: Vec<String>,
    /// With [`DsaOptions::arrival`]: per pixel, the frame at which its contrast arrives.
    pub arrival: Option<Image>,
    /// With [`DsaOptions::arrival`], when the run gives its times: when its arrival frame 0
    /// was taken and how far apart its frames are.
    pub arrival_clock: Option<ArrivalClock>,
}

/// The first frame after the last mask frame (frame 0 of an arrival map).
fn first_after_masks(masks: &[usize]) -> usize {
    masks.iter().max().map_or(0, |&m| m + 1)
}

/// A pixel counts as filled when its largest subtracted value over the run reaches this share
/// of the MIP's 99.5th percentile.
pub const ARRIVAL_MIN_SHARE: f32 = 0.05;

/// Per pixel, the frame at which the contrast arrives, counted from the first frame after the
/// last mask frame (0): the first frame whose subtracted value reaches half the pixel's largest;
/// [`NO_ARRIVAL`] where that largest value stays under [`ARRIVAL_MIN_SHARE`] of the MIP's
/// 99.5th percentile (no vessel).
pub fn arrival_from_frames(subtracted: &[Vec<f32>], masks: &[usize], mip: &[f32]) -> Vec<f32> {
    let first = first_after_masks(masks);
    let positive: Vec<f64> = mip.iter().filter(|v| **v > 0.0).map(|&v| v as f64).collect();
    let floor = ARRIVAL_MIN_SHARE * if positive.is_empty() { 0.0 } else { percentile(&positive, 99.5) as f32 };
    (0..mip.len())
        .map(|i| {
            let mut frames = subtracted.iter().skip(first).map(|f| f[i]);
            let peak = frames.clone().fold(f32::NEG_INFINITY, f32::max);
            if !(peak > 0.0 && peak >= floor) {
                return NO_ARRIVAL;
            }
            frames.position(|v| v >= 0.5 * peak).map_or(NO_ARRIVAL, |k| k as f32)
        })
        .collect()
}

/// DICOM positioner angles → the renderer's TIGRE angles. DICOM: primary angle LAO positive
/// (0 = frontal, source posterior), secondary cranial positive. World (ctadsa): x patient right,
/// y anterior, z superior (RAS), isocentre at the origin; TIGRE primary α puts the source at
/// `(cos α, sin α, 0)·DSO`, so α = primary − 90° and the secondary angle carries over.
pub fn tigre_angles_from_dicom(primary_deg: f64, secondary_deg: f64) -> (f64, f64) {
    (primary_deg - 90.0, secondary_deg)
}

/// The DICOM patient-direction letter of a world (RAS) direction: its dominant axis.
pub fn direction_letter(d: DVec3) -> char {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        if d.x > 0.0 { 'R' } else { 'L' }
    } else if a.y >= a.z {
        if d.y > 0.0 { 'A' } else { 'P' }
    } else if d.z > 0.0 {
        'H'
    } else {
        'F'
    }
}

fn opposite(c: char) -> char {
    match c {
        'R' => 'L',
        'L' => 'R',
        'A' => 'P',
        'P' => 'A',
        'H' => 'F',
        'F' => 'H',
        other => other,
    }
}

fn flip(image: &Image, horizontal: bool, vertical: bool) -> Image {
    let (w, h) = (image.width as usize, image.height as usize);
    let mut data = vec![0.0; w * h];
    for r in 0..h {
        for c in 0..w {
            let (sr, sc) = (if vertical { h - 1 - r } else { r }, if horizontal { w - 1 - c } else { c });
            data[r * w + c] = image.data[sr * w + sc];
        }
    }
    Image { width: image.width, height: image.height, data }
}

/// The options' checks against the run, then its mask frames (0-based).
fn mask_frames(run: &XaRun, o: &DsaOptions) -> Result<Vec<usize>> {
    let path = &run.path;
    if !(o.curve_fraction > 0.0 && o.curve_fraction <= 1.0) {
        return Err(CoreError::invalid(format!("curve fraction must be in (0, 1], got {}", o.curve_fraction)));
    }
    if o.binning < 1 || o.binning > run.columns.min(run.rows) {
        return Err(CoreError::format(
            path,
            format!("binning {} does not fit the {} × {} px images", o.binning, run.columns, run.rows),
        ));
    }
    let n = run.frames.len();
    let masks: Vec<usize> = match (&o.mask_frames, o.subtraction) {
        (_, Subtraction::None) => Vec::new(),
        (Some(m), _) => m.clone(),
        (None, _) if !run.mask_frames.is_empty() => run.mask_frames.clone(),
        (None, _) => vec![0],
    };
    if let Some(&bad) = masks.iter().find(|&&m| m >= n) {
        return Err(CoreError::format(path, format!("mask frame {bad} does not exist (the run has {n} frames)")));
    }
    if o.subtraction != Subtraction::None && n < 2 {
        return Err(CoreError::format(
            path,
            "the run has one frame: subtraction needs a mask and at least one fill frame \
             (use subtraction `none` if the frame is already a subtracted image)",
        ));
    }
    Ok(masks)
}

/// The flips (columns, rows) that bring the run's image into the renderer's orientation for
/// `view` (columns along camera x, rows along camera y), with a note saying why.
fn orientation_flips(run: &XaRun, view: &ConeBeamView, o: &DsaOptions) -> (bool, bool, String) {
    let r = view.rotation();
    let (cam_x, cam_y) = (r.row(0), r.row(1));
    let ours = [direction_letter(cam_x), direction_letter(cam_y)];
    let (flip_h, flip_v) = (o.flip_horizontal, o.flip_vertical);
    match &run.patient_orientation {
        Some(po) if po.len() == 2 => {
            let theirs: Vec<char> = po.iter().map(|s| s.chars().next().unwrap_or('?')).collect();
            let h = theirs[0] == opposite(ours[0]);
            let v = theirs[1] == opposite(ours[1]);
            let note = format!(
                "Patient Orientation {po:?}; renderer expects {}\\{} here → flip columns: {h}, rows: {v}",
                ours[0], ours[1]
            );
            (flip_h ^ h, flip_v ^ v, note)
        }
        _ => (
            flip_h,
            flip_v,
            format!(
                "no Patient Orientation (0020,0020): columns assumed to run towards {} and rows towards {} \
                 (the image as seen from the source); use the flip options otherwise",
                ours[0], ours[1]
            ),
        ),
    }
}

/// Mask, subtraction, frame choice, MIP, orientation and binning of one run.
pub fn dsa_view(run: &XaRun, name: &str, o: &DsaOptions) -> Result<DsaView> {
    let path = &run.path;
    let masks = mask_frames(run, o)?;
    let n = run.frames.len();
    let mut notes = vec![format!("view `{name}` from {}", path.display())];
    let mask = average_frames(&run.frames, &masks);
    let subtracted: Vec<Vec<f32>> = run.frames.iter().map(|f| subtract(&mask, f, o.subtraction)).collect();
    let curve = contrast_curve(&subtracted);
    let frames = match &o.frames {
        Some(r) => {
            if *r.end() >= n || r.start() > r.end() {
                return Err(CoreError::format(path, format!("frame range {r:?} is outside the run's {n} frames")));
            }
            r.clone()
        }
        None => choose_frames(&curve, o.curve_fraction, &masks).ok_or_else(|| {
            CoreError::format(path, "no frame shows contrast after subtraction (wrong mask frame or subtraction?)")
        })?,
    };
    let chosen: Vec<&[f32]> = frames.clone().filter(|f| !masks.contains(f)).map(|f| subtracted[f].as_slice()).collect();
    if chosen.is_empty() {
        return Err(CoreError::format(path, format!("frames {frames:?} are all mask frames")));
    }
    let mip = max_intensity_projection(&chosen);
    let arrival = o.arrival.then(|| Image {
        width: run.columns,
        height: run.rows,
        data: arrival_from_frames(&subtracted, &masks, &mip),
    });
    let image = Image { width: run.columns, height: run.rows, data: mip };
    image.check_finite(path)?;
    notes.push(format!(
        "subtraction {:?}, mask frames {masks:?} (0-based), MIP over frames {}–{}",
        o.subtraction,
        frames.start(),
        frames.end()
    ));
    let g = &run.geometry;
    let (alpha, beta) = tigre_angles_from_dicom(g.primary_deg, g.secondary_deg);
    let geometry = TigreGeometry {
        dsd_mm: g.dsd_mm,
        dso_mm: g.dso_mm,
        detector_px: [run.columns, run.rows],
        pixel_mm: g.pixel_mm,
        offset_mm: [0.0, 0.0],
        primary_deg: alpha,
        secondary_deg: beta,
    };
    let (flip_h, flip_v, note) = orientation_flips(run, &ConeBeamView::from_tigre(&geometry)?, o);
    notes.push(note);
    let image = flip(&image, flip_h, flip_v);
    let b = o.binning.max(1);
    let image = bin_image(&image, b);
    let arrival = arrival.map(|a| bin_arrival(&flip(&a, flip_h, flip_v), b));
    if arrival.is_some() {
        notes.push(format!(
            "arrival map: per pixel the first frame at half its peak, counted from frame {} (0-based)",
            first_after_masks(&masks)
        ));
    }
    let geometry = TigreGeometry {
        detector_px: [image.width, image.height],
        pixel_mm: [g.pixel_mm[0] * b as f64, g.pixel_mm[1] * b as f64],
        ..geometry
    };
    let arrival_clock = match (&arrival, run.acquisition_time_s, run.frame_time_ms) {
        (Some(_), Some(start_s), Some(frame_ms)) => {
            Some(ArrivalClock { start_s: start_s + first_after_masks(&masks) as f64 * frame_ms / 1000.0, frame_ms })
        }
        _ => None,
    };
    Ok(DsaView {
        name: name.to_string(),
        image,
        geometry,
        mask_frames: masks,
        frames,
        curve,
        notes,
        arrival,
        arrival_clock,
    })
}

/// The case's name for the view of run number `index` read from `path`: the index and the file
/// stem, with anything but ASCII letters, digits and `-` as `_` (a safe file name).
pub fn view_name(index: usize, path: &Path) -> String {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("view");
    format!("{index}-{}", stem.replace(|c: char| !c.is_ascii_alphanumeric() && c != '-', "_"))
}

/// Writes a case folder from DSA views and a prior (mesh in world mm). The working volume is the
/// prior's box plus `margin_mm`, or — without a prior — the cube every view sees at the
/// isocentre.
pub fn write_dsa_case(
    out: &Path,
    name: &str,
    views: &[DsaView],
    prior: Option<(&TriMesh, String)>,
    margin_mm: f64,
    voxel_mm: f64,
    mut notes: Vec<String>,
) -> Result<CaseFile> {
    if views.is_empty() {
        return Err(CoreError::invalid("no DSA run given"));
    }
    let size = (views[0].image.width, views[0].image.height);
    if let Some(v) = views.iter().find(|v| (v.image.width, v.image.height) != size) {
        return Err(CoreError::invalid(format!(
            "view `{}` is {} × {} px but `{}` is {} × {} px; all views need one detector size (use binning or crop)",
            v.name, v.image.width, v.image.height, views[0].name, size.0, size.1
        )));
    }
    let max = views.iter().flat_map(|v| v.image.data.iter()).copied().fold(0.0f32, f32::max);
    if !(max > 0.0) {
        return Err(CoreError::invalid("every subtracted image is ≤ 0: no contrast found"));
    }
    let mut entries = Vec::new();
    // Arrival maps for every view or none (a case's are all or nothing).
    let timed = views.iter().all(|v| v.arrival.is_some());
    let offsets = if timed {
        match arrival_offsets(&views.iter().map(|v| v.arrival_clock).collect::<Vec<_>>()) {
            Ok(offsets) => {
                notes.push(format!(
                    "arrival offsets (frames each run's arrival frame 0 was taken after the earliest's, from \
                     Acquisition Time and Frame Time): {offsets:?}"
                ));
                offsets
            }
            Err(why) => {
                notes.push(format!("arrival offsets taken as 0 (all planes imaged at the same instants): {why}"));
                vec![0.0; views.len()]
            }
        }
    } else {
        vec![0.0; views.len()]
    };
    for (v, &arrival_offset_frames) in views.iter().zip(&offsets) {
        entries.push(ViewEntry {
            name: v.name.clone(),
            image: format!("views/{}.tiff", v.name),
            // Set when the PNG is written, below.
            png_scale: Some(1.0),
            preview_png: Some(format!("views/{}.png", v.name)),
            geometry: ViewGeometry::from_tigre(&v.geometry),
            arrival: timed.then(|| format!("views/{}-arrival.tiff", v.name)),
            arrival_offset_frames,
        });
        notes.extend(v.notes.iter().cloned());
    }
    let (min_mm, max_mm) = match prior.as_ref().and_then(|(m, _)| m.bounds_mm()) {
        Some((lo, hi)) => ((lo - DVec3::splat(margin_mm)).to_array(), (hi + DVec3::splat(margin_mm)).to_array()),
        None => {
            let half = views
                .iter()
                .map(|v| {
                    let g = &v.geometry;
                    let m = g.dsd_mm / g.dso_mm;
                    0.5 * (g.detector_px[0] as f64 * g.pixel_mm[0]).min(g.detector_px[1] as f64 * g.pixel_mm[1]) / m
                })
                .fold(f64::INFINITY, f64::min)
                / 3f64.sqrt();
            ([-half; 3], [half; 3])
        }
    };
    let prior_entry = prior.as_ref().map(|(_, description)| PriorEntry {
        mesh: "prior/prior.obj".into(),
        description: description.clone(),
        threshold_mm: None,
    });
    let mut case = CaseFile {
        format: CASE_FORMAT.into(),
        version: CASE_VERSION,
        name: name.to_string(),
        provenance: Provenance {
            source: "DSA runs (DICOM) and a CTA segmentation supplied by the user".into(),
            generator: format!("ctadsa import-dsa {}", env!("CARGO_PKG_VERSION")),
            notes,
        },
        image_values: ImageValues {
            units: "subtracted DSA (ln mask − ln fill for log subtraction), maximum over the filled frames".into(),
            normalised_by: Some(max as f64),
            contrast_per_mm: None,
        },
        volume: VolumeEntry { min_mm, max_mm, voxel_mm },
        views: entries,
        prior: prior_entry,
        ground_truth: None,
    };
    // Nothing is written for a case that would not load.
    case.validate(&out.join(CASE_FILE))?;
    for (v, entry) in views.iter().zip(&mut case.views) {
        let img = Image { data: v.image.data.iter().map(|x| x / max).collect(), ..v.image.clone() };
        write_tiff_f32(&out.join(&entry.image), &img)?;
        entry.png_scale = Some(write_png16(&out.join(format!("views/{}.png", v.name)), &img)?);
        if let (Some(relative), Some(map)) = (&entry.arrival, &v.arrival) {
            write_tiff_f32(&out.join(relative), map)?;
        }
    }
    if let Some((mesh, _)) = prior {
        write_mesh(&out.join("prior/prior.obj"), mesh)?;
    }
    case.save(out)?;
    Ok(case)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn source(primary: f64, secondary: f64) -> DVec3 {
        let (a, b) = tigre_angles_from_dicom(primary, secondary);
        ConeBeamView::from_tigre(&TigreGeometry { primary_deg: a, secondary_deg: b, ..TigreGeometry::reference(0.0) })
            .unwrap()
            .source_mm()
    }

    /// World is RAS (x patient right, y anterior, z head). DICOM: frontal = source posterior,
    /// LAO 90 = detector on the patient's left (source right), cranial = detector towards the
    /// head (source towards the feet).
    #[test]
    fn dicom_angles_put_the_source_where_the_standard_says() {
        let ap = source(0.0, 0.0);
        assert!(ap.y < -499.0 && ap.x.abs() < 1e-9, "frontal: source posterior, got {ap:?}");
        let lao = source(90.0, 0.0);
        assert!(lao.x > 499.0, "LAO 90: source on the patient's right, got {lao:?}");
        let rao = source(-90.0, 0.0);
        assert!(rao.x < -499.0, "RAO 90: source on the patient's left, got {rao:?}");
        let cra = source(0.0, 30.0);
        assert!(cra.z < -200.0 && cra.y < 0.0, "cranial 30: source towards the feet, got {cra:?}");
    }

    #[test]
    fn direction_letters() {
        assert_eq!(direction_letter(DVec3::X), 'R');
        assert_eq!(direction_letter(-DVec3::Y), 'P');
        assert_eq!(direction_letter(DVec3::new(0.1, 0.2, -0.9)), 'F');
    }
}
