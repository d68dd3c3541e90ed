//! Binary masks of the views: the vessel mask of a DSA image (a fraction of its bright
//! percentile) and the silhouette of a solid volume (e.g. the prior) in each view.

use ctadsa_render::ConeBeamView;

use crate::data::case::images::Image;
use crate::data::mesh::TriMesh;
use crate::data::mesh::voxelize::voxelize_mesh;
use crate::data::projector::project_volume;
use crate::data::vessel_evidence::VesselEvidence;
use crate::data::volume::{Grid, Volume};
use crate::stats::percentile;

/// The row-major index of the pixel of `view` that `p` (mm) projects into (the nearest pixel
/// centre), if on the detector: where a point's mask or image value is read.
#[inline]
pub fn pixel_of(view: &ConeBeamView, p: glam::DVec3) -> Option<usize> {
    let uv = view.project(p)?;
    let (c, r) = (uv.x.round(), uv.y.round());
    (c >= 0.0 && r >= 0.0 && c < view.width() as f64 && r < view.height() as f64)
        .then(|| r as usize * view.width() as usize + c as usize)
}

/// A binary image mask (row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub data: Vec<bool>,
}

impl Mask {
    /// Square dilation by `r` pixels (separable max filter).
    pub fn dilated(&self, r: u32) -> Mask {
        if r == 0 {
            return self.clone();
        }
        let (w, h, r) = (self.width as usize, self.height as usize, r as usize);
        let mut tmp = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                tmp[y * w + x] = self.data[y * w + x0..=y * w + x1].iter().any(|&b| b);
            }
        }
        let mut out = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
                out[y * w + x] = (y0..=y1).any(|yy| tmp[yy * w + x]);
            }
        }
        Mask { width: self.width, height: self.height, data: out }
    }

    /// Pixels set in `self` and not in `other`.
    pub fn minus(&self, other: &Mask) -> Mask {
        Mask { data: self.data.iter().zip(&other.data).map(|(&a, &b)| a && !b).collect(), ..self.clone() }
    }

    /// Pixels set in either.
    pub fn or(&self, other: &Mask) -> Mask {
        Mask { data: self.data.iter().zip(&other.data).map(|(&a, &b)| a || b).collect(), ..self.clone() }
    }

    /// Pixels set in both.
    pub fn and(&self, other: &Mask) -> Mask {
        Mask { data: self.data.iter().zip(&other.data).map(|(&a, &b)| a && b).collect(), ..self.clone() }
    }

    /// Number of set pixels.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }
}

/// How many of an image's noise standard deviations ([`noise_sigma`]) a pixel must stand above 0
/// to count as vessel: in a view with quantum or electronic noise a fixed fraction
/// of the bright percentile lies inside the noise, and the masks, seeds and losses built on it
/// would take noise pixels for vessels. With 3 σ about 0.1 % of a noisy background passes. Views
/// whose noise is high against their vessels are read pooled along the vessels instead, at a
/// floor that lets through the same share ([`VesselEvidence`]).
pub const NOISE_FLOOR_SIGMAS: f64 = 3.0;

/// The image's noise standard deviation (image units), estimated without knowing where the
/// vessels are: the median absolute difference of horizontally adjacent pixels over
/// 0.6745 · √2 (the median absolute deviation of the difference of two independent normal
/// draws); vessels cover a minority of the pixels, so their edges do not move the median.
/// 0 for a noise-free synthetic view, whose background is exactly flat.
pub fn noise_sigma(image: &Image) -> f64 {
    let w = image.width as usize;
    if w < 2 {
        return 0.0;
    }
    let mut diffs: Vec<f32> =
        image.data.chunks_exact(w).flat_map(|row| row.windows(2).map(|p| (p[1] - p[0]).abs())).collect();
    if diffs.is_empty() {
        return 0.0;
    }
    let mid = diffs.len() / 2;
    let (_, median, _) = diffs.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*median) / (0.674_489_75 * std::f64::consts::SQRT_2)
}

/// The vessel masks of a run's views: each view's [`VesselEvidence`] above the level at
/// `threshold` (a fraction of the bright percentile, clear of the view's noise).
pub fn vessel_masks(images: &[Image], threshold: f64) -> Vec<Mask> {
    VesselEvidence::of_views(images).iter().map(|e| e.mask(threshold)).collect()
}

/// The pixels of `image` above `level` (and above 0).
pub fn above(image: &Image, level: f64) -> Mask {
    Mask {
        width: image.width,
        height: image.height,
        data: image.data.iter().map(|&v| v as f64 > level && v > 0.0).collect(),
    }
}

/// The contrast per mm (image units per mm) of a solid of chord lengths `chords` (mm per
/// pixel, as [`crate::data::projector::mesh::mesh_chords`]; NaN = unknown) in `image`: the median
/// of `image / chord` over the pixels whose chord exceeds 0.5 mm (a vessel passing behind or in
/// front of the solid adds to its line integral, so most such pixels show the solid alone);
/// 0 where no chord exceeds 0.5 mm.
pub fn contrast_per_mm(image: &Image, chords: &[f32]) -> f64 {
    let ratios: Vec<f64> =
        chords.iter().zip(&image.data).filter(|(c, _)| **c > 0.5).map(|(&c, &v)| v as f64 / c as f64).collect();
    if ratios.is_empty() { 0.0 } else { percentile(&ratios, 50.0) }
}

/// What the solid of chord lengths `chords` (mm per pixel) at `contrast` (image units per mm)
/// leaves of `image`: `image − contrast × chord`; 0 where the chord is unknown (NaN).
pub fn minus_solid(image: &Image, chords: &[f32], contrast: f64) -> Image {
    let data = chords
        .iter()
        .zip(&image.data)
        .map(|(&c, &v)| if c.is_finite() { (v as f64 - contrast * c as f64) as f32 } else { 0.0 })
        .collect();
    Image { data, ..image.clone() }
}

/// Grey-level dilation of a row-major image `width` wide: each pixel the largest value within
/// `r` pixels (a square); NaN wherever one lies within reach.
pub fn max_filtered(values: &[f32], width: usize, r: u32) -> Vec<f32> {
    if r == 0 || width == 0 {
        return values.to_vec();
    }
    let (h, r) = (values.len() / width, r as usize);
    let max = |a: f32, b: f32| if a.is_nan() || b.is_nan() { f32::NAN } else { a.max(b) };
    let mut rows = vec![0.0f32; values.len()];
    for y in 0..h {
        let row = &values[y * width..(y + 1) * width];
        for c in 0..width {
            rows[y * width + c] =
                row[c.saturating_sub(r)..=(c + r).min(width - 1)].iter().fold(f32::MIN, |m, &v| max(m, v));
        }
    }
    let mut out = vec![0.0f32; values.len()];
    for y in 0..h {
        for c in 0..width {
            out[y * width + c] =
                (y.saturating_sub(r)..=(y + r).min(h - 1)).fold(f32::MIN, |m, yy| max(m, rows[yy * width + c]));
        }
    }
    out
}

/// The prior as solid voxels on `grid`.
pub fn prior_solid(prior: &TriMesh, grid: Grid) -> Volume<u8> {
    voxelize_mesh(prior, grid)
}

/// Silhouette of a solid volume in each view (pixels whose ray crosses it).
pub fn silhouettes(solid: &Volume<u8>, views: &[ConeBeamView]) -> Vec<Mask> {
    let f = solid.map(|v| v as f32);
    project_volume(&f, views)
        .into_iter()
        .zip(views)
        .map(|(img, v)| Mask { width: v.width(), height: v.height(), data: img.iter().map(|&x| x > 0.0).collect() })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minus_solid_removes_the_solid_at_its_fitted_contrast_and_keeps_what_lies_behind_it() {
        // A solid of chords 0..4 mm at 2.5 units per mm, a vessel of 0.6 units behind it on
        // three pixels and beside it on one; one pixel of unknown chord.
        let chords: Vec<f32> = vec![0.0, 1.0, 2.0, 3.0, 4.0, 4.0, 3.0, f32::NAN];
        let extra = [0.6, 0.0, 0.0, 0.6, 0.6, 0.0, 0.6, 0.6];
        let data = chords
            .iter()
            .zip(extra)
            .map(|(&c, e)| 2.5 * c.max(0.0) + e)
            .map(|v| if v.is_nan() { 9.0 } else { v })
            .collect();
        let image = Image { width: 8, height: 1, data };
        let mu = contrast_per_mm(&image, &chords);
        assert!((mu - 2.575).abs() < 1e-6, "{mu}");
        let rest = minus_solid(&image, &chords, mu);
        // Median of the ratios (2.5, 2.5, 2.7, 2.65, 2.5, 2.7) over the chords > 0.5 mm: 2.575.
        let expected = [0.6, -0.075, -0.15, 0.375, 0.3, -0.3, 0.375, 0.0];
        for (got, want) in rest.data.iter().zip(expected) {
            assert!((*got as f64 - want).abs() < 1e-5, "{:?}", rest.data);
        }
        // No chord long enough to fit a contrast.
        assert_eq!(contrast_per_mm(&image, &[0.2f32; 8]), 0.0);
    }

    /// A 256² view: a flat background with vessels (bright bands on a fifth of the columns),
    /// plus Gaussian noise of `sigma`.
    fn banded_view(sigma: f64) -> Image {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 256;
        let data = (0..n * n)
            .map(|i| {
                let vessel = if (i % n) % 20 < 4 { 2.0 } else { 0.0 };
                (vessel + sigma * crate::data::projector::noise::standard_normal(&mut rng)) as f32
            })
            .collect();
        Image { width: n as u32, height: n as u32, data }
    }

    #[test]
    fn the_noise_estimate_finds_the_noise_beside_vessels_and_nothing_in_a_clean_view() {
        assert_eq!(noise_sigma(&banded_view(0.0)), 0.0);
        for sigma in [0.02, 0.1, 0.3] {
            let got = noise_sigma(&banded_view(sigma));
            assert!((got / sigma - 1.0).abs() < 0.2, "σ {sigma}: estimated {got}");
        }
        assert_eq!(noise_sigma(&Image { width: 1, height: 3, data: vec![1.0; 3] }), 0.0);
    }

    #[test]
    fn the_vessel_mask_stays_clear_of_the_noise() {
        // Clean: the threshold's fraction of the bright percentile, as before.
        let clean = banded_view(0.0);
        assert!((VesselEvidence::of(&clean, 3).level(0.05) - 0.1).abs() < 1e-9);
        // Noisy: at 0.05 × P99.5 (≈ 0.11) the mask would take a seventh of the background (σ = 0.1);
        // the level rises to the noise floor and keeps the background out, the vessels in.
        let noisy = banded_view(0.1);
        let evidence = VesselEvidence::of(&noisy, 3);
        assert!(evidence.noise_floor > 0.1, "{}", evidence.noise_floor);
        assert_eq!(evidence.level(0.05), evidence.noise_floor);
        let mask = vessel_masks(std::slice::from_ref(&noisy), 0.05).remove(0);
        let n = noisy.width as usize;
        let (mut background, mut vessel) = (0usize, 0usize);
        for (i, &m) in mask.data.iter().enumerate() {
            if (i % n) % 20 < 4 { vessel += m as usize } else { background += m as usize }
        }
        // About 0.1 % of the background alone; the pixels beside the bands add a little (the
        // noise of one half of a line that crosses a band).
        let background_pixels = (0..n).filter(|c| c % 20 >= 4).count() * n;
        assert!(background * 100 < background_pixels, "{background} background pixels in the mask");
        let vessel_pixels = (0..n).filter(|c| c % 20 < 4).count() * n;
        assert_eq!(vessel, vessel_pixels, "every vessel pixel in the mask");
    }
}
