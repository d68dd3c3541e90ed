//! Digital subtraction: mask and fill frames → contrast images (vessels positive), the contrast
//! curve over the run, and the maximum-intensity projection over the filled frames.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};

/// How fill frames are subtracted from the mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Subtraction {
    /// `ln(mask) − ln(fill)`: for frames proportional to detected intensity (Pixel Intensity
    /// Relationship LIN); gives the contrast line integral (Beer–Lambert).
    #[default]
    Log,
    /// `mask − fill`: for frames already log-transformed by the system (relationship LOG).
    Linear,
    /// The frames are already subtracted contrast images (vessels bright); no mask.
    None,
}

impl Subtraction {
    /// Parses `log`, `linear` or `none`.
    pub fn parse(text: &str) -> Result<Self> {
        match text {
            "log" => Ok(Self::Log),
            "linear" => Ok(Self::Linear),
            "none" => Ok(Self::None),
            other => Err(CoreError::invalid(format!("subtraction `{other}`: expected log, linear or none"))),
        }
    }
}

/// The mean of the mask frames (pixel-wise).
pub fn average_frames(frames: &[Vec<f32>], which: &[usize]) -> Vec<f32> {
    let n = which.len().max(1) as f32;
    let mut out = vec![0.0f32; frames.first().map_or(0, Vec::len)];
    for &f in which {
        for (o, v) in out.iter_mut().zip(&frames[f]) {
            *o += v / n;
        }
    }
    out
}

/// One subtracted frame (vessels positive). Log subtraction clamps values below 1 to 1 first.
pub fn subtract(mask: &[f32], fill: &[f32], mode: Subtraction) -> Vec<f32> {
    match mode {
        Subtraction::Log => mask.iter().zip(fill).map(|(&m, &f)| m.max(1.0).ln() - f.max(1.0).ln()).collect(),
        Subtraction::Linear => mask.iter().zip(fill).map(|(&m, &f)| m - f).collect(),
        Subtraction::None => fill.to_vec(),
    }
}

/// The contrast curve: per frame, the mean of the brightest 2 % of subtracted pixels (the
/// opacified vessels), robust to noise and to the background.
pub fn contrast_curve(subtracted: &[Vec<f32>]) -> Vec<f64> {
    subtracted
        .iter()
        .map(|f| {
            let mut v: Vec<f32> = f.iter().copied().filter(|x| x.is_finite()).collect();
            if v.is_empty() {
                return 0.0;
            }
            let k = (v.len() / 50).max(1);
            let split = v.len() - k;
            v.select_nth_unstable_by(split, f32::total_cmp);
            let top = &v[split..];
            let top_mean = top.iter().map(|&x| x as f64).sum::<f64>() / top.len() as f64;
            top_mean.max(0.0)
        })
        .collect()
}

/// The frames to project: the contiguous run around the curve's peak where the contrast is at
/// least `fraction` of the peak, never including `excluded` frames (the masks).
pub fn choose_frames(curve: &[f64], fraction: f64, excluded: &[usize]) -> Option<std::ops::RangeInclusive<usize>> {
    let peak = (0..curve.len()).filter(|i| !excluded.contains(i)).max_by(|&a, &b| curve[a].total_cmp(&curve[b]))?;
    if !(curve[peak] > 0.0) {
        return None;
    }
    let ok = |i: usize| !excluded.contains(&i) && curve[i] >= fraction * curve[peak];
    let (mut lo, mut hi) = (peak, peak);
    while lo > 0 && ok(lo - 1) {
        lo -= 1;
    }
    while hi + 1 < curve.len() && ok(hi + 1) {
        hi += 1;
    }
    Some(lo..=hi)
}

/// Pixel-wise maximum over `frames`.
pub fn max_intensity_projection(frames: &[&[f32]]) -> Vec<f32> {
    let mut out = vec![f32::NEG_INFINITY; frames.first().map_or(0, |f| f.len())];
    for f in frames {
        for (o, &v) in out.iter_mut().zip(f.iter()) {
            *o = o.max(v);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_subtraction_gives_the_line_integral() {
        // Beer–Lambert: fill = mask · exp(−μL) ⇒ ln(mask) − ln(fill) = μL.
        let mask = vec![1000.0f32, 2000.0, 500.0];
        let mu_l = [0.0f32, 0.3, 1.2];
        let fill: Vec<f32> = mask.iter().zip(mu_l).map(|(m, a)| m * (-a).exp()).collect();
        let d = subtract(&mask, &fill, Subtraction::Log);
        for (got, want) in d.iter().zip(mu_l) {
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
        assert_eq!(subtract(&[5.0], &[3.0], Subtraction::Linear), vec![2.0]);
    }

    #[test]
    fn frames_around_the_peak_are_chosen() {
        let curve = [0.0, 0.1, 0.6, 0.9, 1.0, 0.7, 0.2, 0.8];
        assert_eq!(choose_frames(&curve, 0.5, &[0]), Some(2..=5));
        assert_eq!(choose_frames(&curve, 0.5, &[4]), Some(2..=3));
        assert_eq!(choose_frames(&[0.0, 0.0], 0.5, &[]), None);
        assert_eq!(max_intensity_projection(&[&[1.0, 5.0], &[3.0, 2.0]]), vec![3.0, 5.0]);
    }
}
