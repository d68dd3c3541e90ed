//! X-ray angiography runs from DICOM (multi-frame XA, uncompressed): frames, mask frames and the
//! C-arm geometry from the standard positioner tags.

use std::path::{Path, PathBuf};

use ctadsa_render::MAX_ANGLE_DEG;
use dicom_core::{DataElement, PrimitiveValue, Tag, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{DefaultDicomObject, FileMetaTableBuilder, InMemDicomObject, open_file};

use crate::error::{CoreError, Result, write_through_temporary};

/// The C-arm geometry of a run, as the DICOM positioner tags give it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XaGeometry {
    /// Distance Source to Detector (0018,1110), mm.
    pub dsd_mm: f64,
    /// Distance Source to Patient (0018,1111) — to the isocentre, mm.
    pub dso_mm: f64,
    /// Positioner Primary Angle (0018,1510), degrees: LAO positive, RAO negative.
    pub primary_deg: f64,
    /// Positioner Secondary Angle (0018,1511), degrees: cranial positive, caudal negative.
    pub secondary_deg: f64,
    /// Imager Pixel Spacing (0018,1164) as `[column spacing, row spacing]` (mm at the detector).
    pub pixel_mm: [f64; 2],
}

/// One DSA run: the stored frames and what the file says about them.
#[derive(Debug, Clone)]
pub struct XaRun {
    pub path: PathBuf,
    pub columns: u32,
    pub rows: u32,
    /// Frames, row-major, after the modality rescale (slope/intercept) when present.
    pub frames: Vec<Vec<f32>>,
    pub geometry: XaGeometry,
    /// Mask frames named by the file (Mask Subtraction Sequence → Mask Frame Numbers), 0-based.
    pub mask_frames: Vec<usize>,
    /// Pixel Intensity Relationship (0028,1040): "LIN", "LOG" or "DISP", when given.
    pub intensity_relationship: Option<String>,
    /// Patient Orientation (0020,0020): the patient directions of the image rows and columns.
    pub patient_orientation: Option<Vec<String>>,
    /// Frame Time (0018,1063): ms between frames, when given (positive).
    pub frame_time_ms: Option<f64>,
    /// Acquisition Time (0008,0032), else Content Time (0008,0033): when the first frame was
    /// taken, s after midnight ([`super::timing::parse_dicom_time`]), when given.
    pub acquisition_time_s: Option<f64>,
}

fn tag_name(tag: Tag) -> String {
    let name = dicom_dictionary_std::StandardDataDictionary
        .by_tag(tag)
        .map(|e| e.alias.to_string())
        .unwrap_or_else(|| "unknown".into());
    format!("{name} ({:04X},{:04X})", tag.0, tag.1)
}

use dicom_core::dictionary::DataDictionary;

fn element_f64(obj: &DefaultDicomObject, path: &Path, tag: Tag) -> Result<Option<f64>> {
    match obj.element_opt(tag) {
        Ok(Some(e)) => e
            .to_float64()
            .map(Some)
            .map_err(|err| CoreError::format(path, format!("tag {} is not a number: {err}", tag_name(tag)))),
        _ => Ok(None),
    }
}

fn element_str(obj: &DefaultDicomObject, tag: Tag) -> Option<String> {
    obj.element_opt(tag).ok().flatten().and_then(|e| e.to_str().ok()).map(|s| s.trim().to_string())
}

fn element_int(obj: &DefaultDicomObject, path: &Path, tag: Tag) -> Result<Option<i64>> {
    match obj.element_opt(tag) {
        Ok(Some(e)) => e
            .to_int::<i64>()
            .map(Some)
            .map_err(|err| CoreError::format(path, format!("tag {} is not an integer: {err}", tag_name(tag)))),
        _ => Ok(None),
    }
}

/// The most frames a run may claim (a 30 fps run of five minutes is 9,000).
pub const MAX_FRAMES: i64 = 10_000;

/// The most pixels a run's frames may hold together (the frames are kept as `f32`: 2 GiB); a
/// 1024² run of 300 frames is 315 million.
pub const MAX_PIXELS: i64 = 1 << 29;

/// Reads a DSA run. Errors name the file and every missing tag.
pub fn read_xa_run(path: &Path) -> Result<XaRun> {
    if !path.exists() {
        return Err(CoreError::io(path, std::io::Error::new(std::io::ErrorKind::NotFound, "no such file")));
    }
    let bytes = crate::error::read_file(path)?;
    super::dicom_scan::check_dicom_lengths(&bytes).map_err(|problem| CoreError::format(path, problem))?;
    drop(bytes);
    let obj = open_file(path).map_err(|e| CoreError::format(path, format!("not a readable DICOM file: {e}")))?;
    check_modality_and_tags(&obj, path)?;
    let layout = PixelLayout::read(&obj, path)?;
    let frames = read_frames(&obj, path, &layout)?;
    let geometry = read_geometry(&obj, path)?;
    let mut mask_frames = Vec::new();
    if let Ok(Some(seq)) = obj.element_opt(tags::MASK_SUBTRACTION_SEQUENCE)
        && let Some(items) = seq.items()
    {
        for item in items {
            if let Some(e) = item.get(tags::MASK_FRAME_NUMBERS)
                && let Ok(v) = e.to_multi_int::<i64>()
            {
                let n = layout.frames;
                mask_frames.extend(v.into_iter().filter(|&f| f >= 1 && f <= n).map(|f| (f - 1) as usize));
            }
        }
    }
    let patient_orientation = obj
        .element_opt(tags::PATIENT_ORIENTATION)
        .ok()
        .flatten()
        .and_then(|e| e.to_multi_str().ok().map(|v| v.iter().map(|s| s.trim().to_string()).collect()));
    Ok(XaRun {
        path: path.to_path_buf(),
        columns: layout.columns as u32,
        rows: layout.rows as u32,
        frames,
        geometry,
        mask_frames,
        intensity_relationship: element_str(&obj, tags::PIXEL_INTENSITY_RELATIONSHIP),
        patient_orientation,
        // Optional timing: a tag that is not a time is as good as absent (the run still imports;
        // its arrival offset then cannot be told, which the import says).
        frame_time_ms: element_f64(&obj, path, tags::FRAME_TIME).ok().flatten().filter(|t| t.is_finite() && *t > 0.0),
        acquisition_time_s: [tags::ACQUISITION_TIME, tags::CONTENT_TIME]
            .into_iter()
            .find_map(|tag| element_str(&obj, tag).as_deref().and_then(super::timing::parse_dicom_time)),
    })
}

/// XA or RF (the transfer syntax was checked by `check_dicom_lengths`), with every tag the geometry and pixels need.
fn check_modality_and_tags(obj: &DefaultDicomObject, path: &Path) -> Result<()> {
    let modality = element_str(obj, tags::MODALITY).unwrap_or_default();
    if modality != "XA" && modality != "RF" {
        return Err(CoreError::format(
            path,
            format!("modality is `{modality}`, expected XA (X-ray angiography) or RF (fluoroscopy)"),
        ));
    }
    let required = [
        tags::ROWS,
        tags::COLUMNS,
        tags::BITS_ALLOCATED,
        tags::PIXEL_DATA,
        tags::DISTANCE_SOURCE_TO_DETECTOR,
        tags::DISTANCE_SOURCE_TO_PATIENT,
        tags::POSITIONER_PRIMARY_ANGLE,
        tags::POSITIONER_SECONDARY_ANGLE,
        tags::IMAGER_PIXEL_SPACING,
    ];
    let missing: Vec<String> =
        required.iter().filter(|&&t| !matches!(obj.element_opt(t), Ok(Some(_)))).map(|&t| tag_name(t)).collect();
    if !missing.is_empty() {
        return Err(CoreError::format(path, format!("missing DICOM tag(s): {}", missing.join(", "))));
    }
    Ok(())
}

/// Image size, frame count and sample format, range-checked before any pixel is read.
struct PixelLayout {
    rows: i64,
    columns: i64,
    frames: i64,
    bytes_per_sample: usize,
    signed: bool,
}

impl PixelLayout {
    fn read(obj: &DefaultDicomObject, path: &Path) -> Result<Self> {
        let need =
            |v: Option<i64>, tag: Tag| v.ok_or_else(|| CoreError::format(path, format!("missing {}", tag_name(tag))));
        let rows = need(element_int(obj, path, tags::ROWS)?, tags::ROWS)?;
        let columns = need(element_int(obj, path, tags::COLUMNS)?, tags::COLUMNS)?;
        let bits = need(element_int(obj, path, tags::BITS_ALLOCATED)?, tags::BITS_ALLOCATED)?;
        let samples = element_int(obj, path, tags::SAMPLES_PER_PIXEL)?.unwrap_or(1);
        let signed = element_int(obj, path, tags::PIXEL_REPRESENTATION)?.unwrap_or(0) == 1;
        let frames = match element_str(obj, tags::NUMBER_OF_FRAMES) {
            None => 1,
            Some(s) => s
                .parse::<i64>()
                .map_err(|_| CoreError::format(path, format!("Number of Frames (0028,0008) is `{s}`")))?,
        };
        if rows < 1 || columns < 1 || frames < 1 {
            return Err(CoreError::format(
                path,
                format!("degenerate image: {columns} × {rows} pixels, {frames} frames"),
            ));
        }
        if rows > 65_535 || columns > 65_535 {
            return Err(CoreError::format(
                path,
                format!("Rows (0028,0010) × Columns (0028,0011) = {rows} × {columns}: each must be at most 65535"),
            ));
        }
        if frames > MAX_FRAMES {
            return Err(CoreError::format(
                path,
                format!("Number of Frames (0028,0008) is {frames}; at most {MAX_FRAMES} are read"),
            ));
        }
        let pixels = rows * columns * frames;
        if pixels > MAX_PIXELS {
            return Err(CoreError::format(
                path,
                format!(
                    "{columns} × {rows} pixels × {frames} frames is {pixels} pixels; at most {MAX_PIXELS} \
                     (2 GiB as 32-bit values) are read"
                ),
            ));
        }
        if samples != 1 {
            return Err(CoreError::format(path, format!("{samples} samples per pixel; DSA runs are greyscale (1)")));
        }
        if bits != 8 && bits != 16 {
            return Err(CoreError::format(path, format!("Bits Allocated is {bits}; 8 or 16 are supported")));
        }
        Ok(Self { rows, columns, frames, bytes_per_sample: (bits / 8) as usize, signed })
    }
}

/// Every frame's pixels, rescaled by (0028,1053)/(0028,1052).
fn read_frames(obj: &DefaultDicomObject, path: &Path, layout: &PixelLayout) -> Result<Vec<Vec<f32>>> {
    let pixels = obj
        .element(tags::PIXEL_DATA)
        .map_err(|e| CoreError::format(path, format!("Pixel Data: {e}")))?
        .to_bytes()
        .map_err(|e| CoreError::format(path, format!("Pixel Data is not native (encapsulated?): {e}")))?;
    let (rows, columns, n_frames, bytes_per) = (layout.rows, layout.columns, layout.frames, layout.bytes_per_sample);
    let per_frame = (rows * columns) as usize;
    // Bounded above: 65535² × 10⁴ × 2 bytes fits in u64 and in usize on 64-bit targets.
    let needed = (per_frame as u64).saturating_mul(n_frames as u64).saturating_mul(bytes_per as u64);
    if (pixels.len() as u64) < needed {
        return Err(CoreError::format(
            path,
            format!(
                "Pixel Data holds {} bytes, {columns} × {rows} × {n_frames} frames × {bytes_per} bytes need {needed}",
                pixels.len()
            ),
        ));
    }
    let slope = element_f64(obj, path, tags::RESCALE_SLOPE)?.unwrap_or(1.0);
    let intercept = element_f64(obj, path, tags::RESCALE_INTERCEPT)?.unwrap_or(0.0);
    let value = |i: usize| -> f32 {
        let raw = match (bytes_per, layout.signed) {
            (1, false) => pixels[i] as f64,
            (1, true) => pixels[i] as i8 as f64,
            (_, false) => u16::from_le_bytes([pixels[2 * i], pixels[2 * i + 1]]) as f64,
            (_, true) => i16::from_le_bytes([pixels[2 * i], pixels[2 * i + 1]]) as f64,
        };
        (raw * slope + intercept) as f32
    };
    Ok((0..n_frames as usize).map(|f| (0..per_frame).map(|p| value(f * per_frame + p)).collect()).collect())
}

/// The C-arm geometry: distances, angles and detector pixel spacing, range-checked.
fn read_geometry(obj: &DefaultDicomObject, path: &Path) -> Result<XaGeometry> {
    let spacing = obj
        .element(tags::IMAGER_PIXEL_SPACING)
        .map_err(|e| CoreError::format(path, e.to_string()))?
        .to_multi_float64()
        .map_err(|e| CoreError::format(path, format!("Imager Pixel Spacing (0018,1164): {e}")))?;
    if spacing.len() != 2 || spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(CoreError::format(
            path,
            format!("Imager Pixel Spacing (0018,1164) must be two positive numbers, got {spacing:?}"),
        ));
    }
    let get = |t: Tag| -> Result<f64> {
        element_f64(obj, path, t)?.ok_or_else(|| CoreError::format(path, format!("missing {}", tag_name(t))))
    };
    let geometry = XaGeometry {
        dsd_mm: get(tags::DISTANCE_SOURCE_TO_DETECTOR)?,
        dso_mm: get(tags::DISTANCE_SOURCE_TO_PATIENT)?,
        primary_deg: get(tags::POSITIONER_PRIMARY_ANGLE)?,
        secondary_deg: get(tags::POSITIONER_SECONDARY_ANGLE)?,
        // (0018,1164) is row spacing \ column spacing.
        pixel_mm: [spacing[1], spacing[0]],
    };
    if !(geometry.primary_deg.abs() <= MAX_ANGLE_DEG && geometry.secondary_deg.abs() <= MAX_ANGLE_DEG) {
        return Err(CoreError::format(
            path,
            format!(
                "Positioner Primary/Secondary Angle (0018,1510)/(0018,1511) must be degrees within ±360, got {} / {}",
                geometry.primary_deg, geometry.secondary_deg
            ),
        ));
    }
    if !(geometry.dso_mm > 0.0 && geometry.dsd_mm > geometry.dso_mm && geometry.dsd_mm.is_finite()) {
        return Err(CoreError::format(
            path,
            format!(
                "need 0 < Distance Source to Patient ({} mm) < Distance Source to Detector ({} mm)",
                geometry.dso_mm, geometry.dsd_mm
            ),
        ));
    }
    Ok(geometry)
}

/// What [`write_xa_run`] writes; `None` leaves a tag out (to test errors).
#[derive(Debug, Clone)]
pub struct XaRunSpec {
    pub modality: String,
    pub columns: u16,
    pub rows: u16,
    /// Frames as 16-bit values, row-major.
    pub frames: Vec<Vec<u16>>,
    pub dsd_mm: Option<f64>,
    pub dso_mm: Option<f64>,
    pub primary_deg: Option<f64>,
    pub secondary_deg: Option<f64>,
    /// `[column spacing, row spacing]` mm.
    pub pixel_mm: Option<[f64; 2]>,
    /// 1-based mask frame numbers (Mask Subtraction Sequence).
    pub mask_frame_numbers: Vec<u16>,
    pub intensity_relationship: Option<String>,
    /// Patient Orientation (0020,0020): row direction, column direction (e.g. `["L", "F"]`).
    pub patient_orientation: Option<[String; 2]>,
    /// Names the study: runs written with the same key share a Study Instance UID (and Patient
    /// ID); each run is its own series.
    pub study_key: String,
    /// Series Number (0020,0011); also the run's part of its UIDs.
    pub series_number: u32,
    /// Acquisition Time (0008,0032), s after midnight: when the first frame was taken (frames
    /// are [`SIMULATED_FRAME_TIME_MS`] apart).
    pub acquisition_time_s: Option<f64>,
}

/// Frame Time (0018,1063) of the runs [`write_xa_run`] writes: ms between frames.
pub const SIMULATED_FRAME_TIME_MS: f64 = 100.0;

/// Seconds after midnight as a DICOM time (TM, `HHMMSS.FFFFFF`), within the day.
fn dicom_time(seconds: f64) -> String {
    let micros = (seconds.rem_euclid(86_400.0) * 1e6).round() as u64 % 86_400_000_000;
    let (s, f) = (micros / 1_000_000, micros % 1_000_000);
    format!("{:02}{:02}{:02}.{f:06}", s / 3600, s / 60 % 60, s % 60)
}

/// A DICOM UID under the `2.25` root (ISO/IEC 9834-8: a 128-bit number in decimal), derived
/// from `parts` with FNV-1a (128 bit): the same inputs give the same UID, so exports are
/// reproducible.
pub fn derived_uid(parts: &[&[u8]]) -> String {
    let mut h: u128 = 0x6c62_272e_07bb_0142_62b8_2175_6295_c58d;
    for part in parts {
        for &b in part.iter().chain(&[0xff]) {
            h ^= b as u128;
            h = h.wrapping_mul(0x0000_0000_0100_0000_0000_0000_0000_013b);
        }
    }
    format!("2.25.{h}")
}

/// Writes a multi-frame XA file (explicit VR little endian, 16-bit unsigned) — for tests and for
/// exporting synthetic runs to tools that read DICOM; atomically (a temporary beside it, renamed).
pub fn write_xa_run(path: &Path, spec: &XaRunSpec) -> Result<()> {
    let ds = |v: f64| PrimitiveValue::from(format!("{v}"));
    let pixel_bytes: Vec<u8> = spec.frames.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let (key, series) = (spec.study_key.as_bytes(), spec.series_number.to_le_bytes());
    let study_uid = derived_uid(&[b"study", key]);
    let series_uid = derived_uid(&[b"series", key, &series]);
    let instance_uid = derived_uid(&[b"instance", key, &series, &pixel_bytes]);
    let empty = |tag: Tag, vr: VR| DataElement::new(tag, vr, PrimitiveValue::Empty);
    let mut obj = InMemDicomObject::from_element_iter([
        DataElement::new(tags::SOP_CLASS_UID, VR::UI, uids::X_RAY_ANGIOGRAPHIC_IMAGE_STORAGE),
        DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, instance_uid.as_str()),
        // Simulated from a case's line integrals, not acquired: derived, secondary.
        DataElement::new(tags::IMAGE_TYPE, VR::CS, "DERIVED\\SECONDARY\\SINGLE PLANE"),
        DataElement::new(tags::MODALITY, VR::CS, spec.modality.as_str()),
        DataElement::new(tags::MANUFACTURER, VR::LO, "ctadsa (simulated run)"),
        // Patient and study: the case, anonymous by construction.
        DataElement::new(tags::PATIENT_NAME, VR::PN, "SIMULATED^PHANTOM"),
        DataElement::new(tags::PATIENT_ID, VR::LO, spec.study_key.as_str()),
        empty(tags::PATIENT_BIRTH_DATE, VR::DA),
        empty(tags::PATIENT_SEX, VR::CS),
        DataElement::new(tags::STUDY_INSTANCE_UID, VR::UI, study_uid.as_str()),
        empty(tags::STUDY_DATE, VR::DA),
        empty(tags::STUDY_TIME, VR::TM),
        empty(tags::REFERRING_PHYSICIAN_NAME, VR::PN),
        DataElement::new(tags::STUDY_ID, VR::SH, "1"),
        empty(tags::ACCESSION_NUMBER, VR::SH),
        DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, series_uid.as_str()),
        DataElement::new(tags::SERIES_NUMBER, VR::IS, format!("{}", spec.series_number).as_str()),
        // Unknown (present, empty): dciodvfy requires it for XA.
        empty(tags::LATERALITY, VR::CS),
        DataElement::new(tags::INSTANCE_NUMBER, VR::IS, "1"),
        // X-ray acquisition: exposure values unknown (type 2: present, empty).
        empty(tags::KVP, VR::DS),
        DataElement::new(tags::RADIATION_SETTING, VR::CS, "GR"),
        empty(tags::EXPOSURE_TIME, VR::IS),
        empty(tags::X_RAY_TUBE_CURRENT, VR::IS),
        empty(tags::EXPOSURE, VR::IS),
        DataElement::new(tags::POSITIONER_MOTION, VR::CS, "STATIC"),
        // Multi-frame: frames 100 ms apart.
        DataElement::new(tags::FRAME_TIME, VR::DS, ds(SIMULATED_FRAME_TIME_MS)),
        DataElement::new(
            tags::FRAME_INCREMENT_POINTER,
            VR::AT,
            PrimitiveValue::Tags(std::iter::once(tags::FRAME_TIME).collect()),
        ),
        DataElement::new(tags::RECOMMENDED_VIEWING_MODE, VR::CS, "SUB"),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
        DataElement::new(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"),
        DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, format!("{}", spec.frames.len()).as_str()),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(spec.rows)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(spec.columns)),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(16u16)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(16u16)),
        DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(15u16)),
        DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(0u16)),
    ]);
    let opt = |obj: &mut InMemDicomObject, tag: Tag, v: Option<f64>| {
        if let Some(v) = v {
            obj.put(DataElement::new(tag, VR::DS, ds(v)));
        }
    };
    if let Some(t) = spec.acquisition_time_s {
        obj.put(DataElement::new(tags::ACQUISITION_TIME, VR::TM, dicom_time(t).as_str()));
    }
    opt(&mut obj, tags::DISTANCE_SOURCE_TO_DETECTOR, spec.dsd_mm);
    opt(&mut obj, tags::DISTANCE_SOURCE_TO_PATIENT, spec.dso_mm);
    opt(&mut obj, tags::POSITIONER_PRIMARY_ANGLE, spec.primary_deg);
    opt(&mut obj, tags::POSITIONER_SECONDARY_ANGLE, spec.secondary_deg);
    if let Some([c, r]) = spec.pixel_mm {
        obj.put(DataElement::new(tags::IMAGER_PIXEL_SPACING, VR::DS, PrimitiveValue::from(format!("{r}\\{c}"))));
    }
    match &spec.patient_orientation {
        Some([a, b]) => {
            obj.put(DataElement::new(tags::PATIENT_ORIENTATION, VR::CS, PrimitiveValue::from(format!("{a}\\{b}"))))
        }
        None => obj.put(empty(tags::PATIENT_ORIENTATION, VR::CS)),
    };
    if let Some(rel) = &spec.intensity_relationship {
        obj.put(DataElement::new(tags::PIXEL_INTENSITY_RELATIONSHIP, VR::CS, rel.as_str()));
    }
    if !spec.mask_frame_numbers.is_empty() {
        let item = InMemDicomObject::from_element_iter([
            DataElement::new(tags::MASK_OPERATION, VR::CS, "AVG_SUB"),
            DataElement::new(
                tags::MASK_FRAME_NUMBERS,
                VR::US,
                PrimitiveValue::U16(spec.mask_frame_numbers.iter().copied().collect()),
            ),
        ]);
        obj.put(DataElement::new(
            tags::MASK_SUBTRACTION_SEQUENCE,
            VR::SQ,
            dicom_core::value::DataSetSequence::from(vec![item]),
        ));
    }
    obj.put(DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::from(pixel_bytes)));
    let file = obj
        .with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .map_err(|e| CoreError::format(path, format!("cannot build DICOM meta: {e}")))?;
    write_through_temporary(path, "dcm", |tmp| {
        file.write_to_file(tmp).map_err(|e| CoreError::format(path, format!("cannot write DICOM: {e}")))
    })
}
