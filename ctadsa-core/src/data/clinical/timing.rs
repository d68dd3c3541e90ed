//! When a run's frames were taken: a biplane system images its two planes alternately, so the
//! same frame number is a different instant in each; the arrival maps of the two planes agree
//! only once each plane's offset is known ([`crate::data::case::ViewEntry::arrival_offset_frames`]).

use crate::data::case::MAX_ARRIVAL_OFFSET_FRAMES;

/// The clock of a run's arrival map: when its arrival frame 0 was taken and how far apart its
/// frames are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArrivalClock {
    /// Time of day (s after midnight) of the frame the arrival map counts as 0.
    pub start_s: f64,
    /// Frame Time (0018,1063): ms between frames.
    pub frame_ms: f64,
}

/// A DICOM time (TM: `HH`, `HHMM`, `HHMMSS` or `HHMMSS.F…`, the old `HH:MM:SS` too) as seconds
/// after midnight; `None` when it is not one.
pub fn parse_dicom_time(text: &str) -> Option<f64> {
    let text = text.trim().replace(':', "");
    let (whole, fraction) = text.split_once('.').unwrap_or((&text, ""));
    if whole.is_empty() || whole.len() > 6 || whole.len() % 2 == 1 || !whole.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    if !fraction.bytes().all(|b| b.is_ascii_digit()) || (!fraction.is_empty() && whole.len() != 6) {
        return None;
    }
    let part = |k: usize| whole.get(2 * k..2 * k + 2).map_or(Some(0), |p| p.parse::<u32>().ok());
    let (h, m, s) = (part(0)?, part(1)?, part(2)?);
    if h > 23 || m > 59 || s > 60 {
        return None;
    }
    let fraction = if fraction.is_empty() { 0.0 } else { format!("0.{fraction}").parse::<f64>().ok()? };
    Some(f64::from(h * 3600 + m * 60 + s) + fraction)
}

/// Per run, how late (frames) its arrival frames were taken after the earliest run's
/// ([`crate::data::case::ViewEntry::arrival_offset_frames`]), from their clocks; an error says
/// why they cannot be told (a run without its times, runs at different frame rates, runs far
/// apart), and the offsets are then best taken as 0.
pub fn arrival_offsets(clocks: &[Option<ArrivalClock>]) -> Result<Vec<f64>, String> {
    let Some(clocks) = clocks.iter().copied().collect::<Option<Vec<_>>>() else {
        return Err("a run gives no Acquisition Time (0008,0032) or Frame Time (0018,1063)".into());
    };
    let Some(first) = clocks.first() else { return Ok(vec![]) };
    if let Some(c) = clocks.iter().find(|c| (c.frame_ms - first.frame_ms).abs() > 1e-3 * first.frame_ms) {
        return Err(format!(
            "the runs' frames are {} ms and {} ms apart: different frame rates",
            first.frame_ms, c.frame_ms
        ));
    }
    let earliest = clocks.iter().map(|c| c.start_s).fold(f64::INFINITY, f64::min);
    let offsets: Vec<f64> = clocks.iter().map(|c| (c.start_s - earliest) * 1000.0 / first.frame_ms).collect();
    match offsets.iter().find(|&&o| o > MAX_ARRIVAL_OFFSET_FRAMES) {
        Some(o) => Err(format!("the runs start {o:.0} frames apart: not one biplane run")),
        None => Ok(offsets),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dicom_times_read_as_seconds_after_midnight() {
        assert_eq!(parse_dicom_time("120000"), Some(43_200.0));
        assert_eq!(parse_dicom_time("070907.0705 "), Some(7.0 * 3600.0 + 9.0 * 60.0 + 7.0705));
        assert_eq!(parse_dicom_time("1012"), Some(36_720.0));
        assert_eq!(parse_dicom_time("10"), Some(36_000.0));
        assert_eq!(parse_dicom_time("10:12:30"), Some(36_750.0));
        for bad in ["", "1", "12345", "250000", "126000", "1200.5", "12a000", "120000.x", "1234567"] {
            assert_eq!(parse_dicom_time(bad), None, "{bad}");
        }
    }

    /// Two planes at 7.5 frames/s, the lateral's frame 0 taken 66.7 ms (half a frame) after the
    /// frontal's: 0 and 0.5 frames; any order; what cannot be told says why.
    #[test]
    fn offsets_are_frames_after_the_earliest_run() {
        let clock = |start_s, frame_ms| Some(ArrivalClock { start_s, frame_ms });
        let ms = 1000.0 / 7.5;
        let offsets = arrival_offsets(&[clock(100.0 + 0.5 * ms / 1000.0, ms), clock(100.0, ms)]).unwrap();
        assert!((offsets[0] - 0.5).abs() < 1e-9 && offsets[1] == 0.0, "{offsets:?}");
        assert!(arrival_offsets(&[clock(100.0, ms), None]).unwrap_err().contains("Acquisition Time"));
        assert!(arrival_offsets(&[clock(100.0, ms), clock(100.0, 2.0 * ms)]).unwrap_err().contains("frame rates"));
        assert!(arrival_offsets(&[clock(100.0, ms), clock(3000.0, ms)]).unwrap_err().contains("apart"));
    }
}
