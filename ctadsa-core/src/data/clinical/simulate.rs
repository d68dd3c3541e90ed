//! Simulated DSA runs: a case's line-integral image turned into the frames an angio suite would
//! record (a static background attenuated by a contrast bolus), for tests and for trying the
//! DICOM path end to end without patient data.

use ctadsa_render::TigreGeometry;

use super::import::tigre_angles_from_dicom;
use super::xa::XaRunSpec;
use crate::data::case::images::Image;

/// Contrast over the run's 8 frames; frame 0 is the mask.
pub const BOLUS: [f32; 8] = [0.0, 0.1, 0.4, 0.9, 1.0, 0.7, 0.3, 0.1];

/// The frames of a run: `fill_t = I0 · exp(−κ c(t) L)` with a textured background `I0` (about
/// 14,000–26,000 counts) and `c(t)` = [`BOLUS`], as 16-bit counts. `mirror` stores the frames
/// left-right mirrored (as a viewer facing the patient sees a frontal run).
pub fn simulated_frames(line_integral: &Image, kappa: f32, mirror: bool) -> Vec<Vec<u16>> {
    let (w, h) = (line_integral.width as usize, line_integral.height as usize);
    BOLUS
        .iter()
        .map(|&c| {
            let mut f = vec![0u16; w * h];
            for r in 0..h {
                for col in 0..w {
                    let i = r * w + col;
                    let background = 20_000.0 + 6_000.0 * ((r as f32 * 0.13).sin() * (col as f32 * 0.07).cos());
                    let v = background * (-kappa * c * line_integral.data[i]).exp();
                    f[if mirror { r * w + (w - 1 - col) } else { i }] = v.round().clamp(0.0, 65535.0) as u16;
                }
            }
            f
        })
        .collect()
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
    }
}
