//! Simulated DSA runs: a case's line-integral image turned into the frames an angio suite would
//! record (a static background attenuated by a contrast bolus), for tests and for trying the
//! DICOM path end to end without patient data.

use ctadsa_render::TigreGeometry;

use super::import::tigre_angles_from_dicom;
use super::xa::{SIMULATED_FRAME_TIME_MS, XaRunSpec};
use crate::data::case::images::Image;
use crate::data::case::{Case, ViewGeometry};
use crate::error::{CoreError, Result};

/// Contrast over the run's 8 frames; frame 0 is the mask.
pub const BOLUS: [f32; 8] = [0.0, 0.1, 0.4, 0.9, 1.0, 0.7, 0.3, 0.1];

/// The frames of a run: `fill_t = I0 · exp(−κ c(t) L)` with a textured background `I0` (about
/// 14,000–26,000 counts) and `c(t)` = [`BOLUS`], as 16-bit counts. `mirror` stores the frames
/// left-right mirrored (as a viewer facing the patient sees a frontal run).
pub fn simulated_frames(line_integral: &Image, kappa: f32, mirror: bool) -> Vec<Vec<u16>> {
    BOLUS.iter().map(|&c| frame(line_integral, kappa, mirror, |_| c)).collect()
}

/// The `frames` frames of a time-resolved run ([`crate::data::case::ViewEntry::arrival`]):
/// frame 0 the mask; a pixel's contrast turns on (and stays) in the frame after its arrival
/// (`arrival` 0 → frame 1; a pixel no vessel fills turns on in frame 1). Background and counts
/// as [`simulated_frames`].
pub fn simulated_timed_frames(
    line_integral: &Image,
    arrival: &Image,
    frames: usize,
    kappa: f32,
    mirror: bool,
) -> Vec<Vec<u16>> {
    (0..frames)
        .map(|k| {
            frame(line_integral, kappa, mirror, |i| if (arrival.data[i].max(0.0) as usize) < k { 1.0 } else { 0.0 })
        })
        .collect()
}

/// One frame: `I0 · exp(−κ c_i L_i)` over the textured background, pixel `i`'s contrast
/// `c_i = contrast(i)`, as 16-bit counts (mirrored left-right with `mirror`).
fn frame(line_integral: &Image, kappa: f32, mirror: bool, contrast: impl Fn(usize) -> f32) -> Vec<u16> {
    let (w, h) = (line_integral.width as usize, line_integral.height as usize);
    let mut f = vec![0u16; w * h];
    for r in 0..h {
        for col in 0..w {
            let i = r * w + col;
            let background = 20_000.0 + 6_000.0 * ((r as f32 * 0.13).sin() * (col as f32 * 0.07).cos());
            let v = background * (-kappa * contrast(i) * line_integral.data[i]).exp();
            f[if mirror { r * w + (w - 1 - col) } else { i }] = v.round().clamp(0.0, 65535.0) as u16;
        }
    }
    f
}

/// The largest peak attenuation (κ × the largest line integral) [`simulated_case_runs`] takes.
pub const MAX_PEAK_ATTENUATION: f32 = 5.0;

/// Simulated DSA runs of every view of a case (TIGRE geometry without detector offsets;
/// time-resolved, [`simulated_timed_frames`], when the case has arrival maps), one
/// study per case and one series per view, with the contrast's peak attenuation
/// `peak_attenuation` (κ × the largest line integral). `mirror_first` stores the first (frontal)
/// run mirrored with Patient Orientation `L\F`, as a viewer facing the patient sees it. Returns
/// `(view name, run)` pairs for [`super::xa::write_xa_run`].
pub fn simulated_case_runs(case: &Case, peak_attenuation: f32, mirror_first: bool) -> Result<Vec<(String, XaRunSpec)>> {
    // The background is 14,000–26,000 counts: past e^-5 its darkest pixels keep under 100 of the
    // 16-bit counts and a log subtraction loses the vessel there.
    if !(peak_attenuation > 0.0 && peak_attenuation <= MAX_PEAK_ATTENUATION) {
        return Err(CoreError::invalid(format!(
            "peak attenuation must be in (0, {MAX_PEAK_ATTENUATION}], got {peak_attenuation}"
        )));
    }
    let max = case.images.iter().map(|i| i.max()).fold(0.0f32, f32::max);
    if !(max > 0.0) {
        return Err(CoreError::format(&case.dir, "every image is 0: nothing to simulate"));
    }
    let arrivals = case.arrival_maps()?;
    // Both planes of a biplane run record the same frames: the mask, one per arrival frame of
    // any view, and two more.
    let frames = arrivals
        .as_ref()
        .map_or(0, |maps| maps.iter().flat_map(|m| m.data.iter().copied()).fold(0.0f32, f32::max) as usize + 3);
    let mut runs = Vec::new();
    for (i, (entry, img)) in case.file.views.iter().zip(&case.images).enumerate() {
        let ViewGeometry::Tigre { dsd_mm, dso_mm, detector_px, pixel_mm, offset_mm, primary_deg, secondary_deg } =
            entry.geometry
        else {
            return Err(CoreError::format(
                &case.dir,
                format!("view `{}` has matrix geometry; DICOM positioner tags need C-arm angles", entry.name),
            ));
        };
        if offset_mm != [0.0, 0.0] {
            return Err(CoreError::format(
                &case.dir,
                format!("view `{}`: detector offsets cannot be written as DICOM tags", entry.name),
            ));
        }
        let g = TigreGeometry { dsd_mm, dso_mm, detector_px, pixel_mm, offset_mm, primary_deg, secondary_deg };
        let mirror = mirror_first && i == 0;
        let mut spec = simulated_run(img, &g, peak_attenuation / max, mirror);
        if let Some(maps) = &arrivals {
            spec.frames = simulated_timed_frames(img, &maps[i], frames, peak_attenuation / max, mirror);
            // Noon, and a plane whose frames were taken late (its arrival offset) that much later.
            spec.acquisition_time_s =
                Some(12.0 * 3600.0 + entry.arrival_offset_frames * SIMULATED_FRAME_TIME_MS / 1000.0);
        }
        if mirror {
            spec.patient_orientation = Some(["L".into(), "F".into()]);
        }
        spec.study_key = case.file.name.clone();
        spec.series_number = i as u32 + 1;
        runs.push((entry.name.clone(), spec));
    }
    Ok(runs)
}

/// A complete run description for [`super::xa::write_xa_run`] from a view's TIGRE geometry.
pub fn simulated_run(line_integral: &Image, geometry: &TigreGeometry, kappa: f32, mirror: bool) -> XaRunSpec {
    // Invert tigre_angles_from_dicom: primary = α + 90°.
    let (alpha0, _) = tigre_angles_from_dicom(0.0, 0.0);
    XaRunSpec {
        modality: "XA".into(),
        columns: line_integral.width as u16,
        rows: line_integral.height as u16,
        frames: simulated_frames(line_integral, kappa, mirror),
        dsd_mm: Some(geometry.dsd_mm),
        dso_mm: Some(geometry.dso_mm),
        primary_deg: Some(geometry.primary_deg - alpha0),
        secondary_deg: Some(geometry.secondary_deg),
        pixel_mm: Some(geometry.pixel_mm),
        mask_frame_numbers: vec![1],
        intensity_relationship: Some("LIN".into()),
        patient_orientation: None,
        study_key: "simulated".into(),
        series_number: 1,
        acquisition_time_s: None,
    }
}
