//! A mesh's chord image matched to a view. An X-ray image is not the sharp line integral of the
//! solid a vessel mesh bounds: the mesh is an iso-surface that sits inside the imaged vessel's
//! partial-volume edge (thin vessels lose most), the detector and the focal spot blur edges, and
//! a registration leaves sub-pixel offsets. Subtracting the mesh's chords from such an image
//! leaves a positive ring along every edge and along every thin vessel — where a vessel that
//! leaves the mesh or passes behind it should show. The chords of the mesh moved outward by the
//! offset, and blurred by the Gaussian, that best explain the image on the mesh's footprint
//! remove most of it; offset, blur and contrast per mm are fitted together.

use ctadsa_render::ConeBeamView;

use crate::data::case::images::Image;
use crate::data::masks::contrast_per_mm;
use crate::data::mesh::TriMesh;
use crate::data::projector::mesh::mesh_chords;
use crate::error::Result;

/// Blurs tried by [`fit_blur`] (Gaussian σ, pixels).
pub const BLUR_SIGMAS_PX: [f64; 7] = [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0];

/// Outward offsets of the mesh tried by [`fit_mesh_projection`] (mm).
pub const OFFSETS_MM: [f64; 5] = [0.0, 0.1, 0.2, 0.3, 0.4];

/// Footprint of the fit: pixels where the widest tried blur of the chords exceeds this (mm).
const FOOTPRINT_MM: f32 = 0.05;

/// `values` (row-major, `width` wide) blurred by a Gaussian of `sigma_px` pixels (truncated at
/// 3σ, renormalised at the borders); NaN stays NaN and counts as 0 for its neighbours.
pub fn gaussian_blurred(values: &[f32], width: usize, sigma_px: f64) -> Vec<f32> {
    if sigma_px <= 0.0 || width == 0 {
        return values.to_vec();
    }
    let height = values.len() / width;
    let r = (3.0 * sigma_px).ceil() as usize;
    let kernel: Vec<f64> = (0..=r).map(|k| (-0.5 * (k as f64 / sigma_px).powi(2)).exp()).collect();
    let finite = |v: f32| if v.is_finite() { v as f64 } else { 0.0 };
    let pass = |input: &[f64], len: usize, stride: usize, lines: usize, step: usize| -> Vec<f64> {
        let mut out = vec![0.0; input.len()];
        for line in 0..lines {
            let base = line * step;
            for i in 0..len {
                let (mut sum, mut weight) = (0.0, 0.0);
                for j in i.saturating_sub(r)..=(i + r).min(len - 1) {
                    let w = kernel[i.abs_diff(j)];
                    sum += w * input[base + j * stride];
                    weight += w;
                }
                out[base + i * stride] = sum / weight;
            }
        }
        out
    };
    let plain: Vec<f64> = values.iter().map(|&v| finite(v)).collect();
    let rows = pass(&plain, width, 1, height, width);
    let both = pass(&rows, height, width, width, 1);
    both.iter().zip(values).map(|(&b, &v)| if v.is_nan() { f32::NAN } else { b as f32 }).collect()
}

/// The chords blurred to match `image`, with the blur and the contrast per mm that fit it.
#[derive(Debug, Clone)]
pub struct MatchedChords {
    /// The mesh's outward offset (mm; 0 for [`fit_blur`]).
    pub offset_mm: f64,
    /// Mean absolute residual over the footprint (image units).
    pub cost: f64,
    /// Gaussian σ (pixels), one of [`BLUR_SIGMAS_PX`].
    pub sigma_px: f64,
    /// Image units per mm of chord ([`contrast_per_mm`] of the blurred chords).
    pub contrast_per_mm: f64,
    /// The blurred chords (mm), row-major like the image.
    pub chords: Vec<f32>,
}

/// Of the blurs in `sigmas_px`, the one whose blurred `chords` × their fitted contrast leave the
/// smallest absolute residual of `image` over the solid's footprint (where the widest blur
/// reaches `FOOTPRINT_MM`). The absolute residual, not its square: the vessels the solid lacks
/// lie on that footprint too and must not pull the fit. Ties go to the sharper blur.
pub fn fit_blur(image: &Image, chords: &[f32], sigmas_px: &[f64]) -> MatchedChords {
    let widest = sigmas_px.iter().copied().fold(0.0, f64::max);
    fit_blur_on(image, chords, sigmas_px, &footprint(chords, image.width as usize, widest))
}

/// Pixels where `chords` blurred by `sigma_px` exceed `FOOTPRINT_MM`.
fn footprint(chords: &[f32], width: usize, sigma_px: f64) -> Vec<usize> {
    gaussian_blurred(chords, width, sigma_px)
        .iter()
        .enumerate()
        .filter(|(_, c)| **c > FOOTPRINT_MM)
        .map(|(i, _)| i)
        .collect()
}

/// [`fit_blur`] over the given `footprint` pixels.
fn fit_blur_on(image: &Image, chords: &[f32], sigmas_px: &[f64], footprint: &[usize]) -> MatchedChords {
    let width = image.width as usize;
    let mut best: Option<MatchedChords> = None;
    for &sigma_px in sigmas_px {
        let blurred = gaussian_blurred(chords, width, sigma_px);
        let contrast = contrast_per_mm(image, &blurred);
        let cost = footprint
            .iter()
            .filter(|&&i| blurred[i].is_finite())
            .map(|&i| (image.data[i] as f64 - contrast * blurred[i] as f64).abs())
            .sum::<f64>()
            / footprint.len().max(1) as f64;
        if best.as_ref().is_none_or(|b| cost < b.cost) {
            best = Some(MatchedChords { offset_mm: 0.0, cost, sigma_px, contrast_per_mm: contrast, chords: blurred });
        }
    }
    best.unwrap_or_else(|| MatchedChords {
        offset_mm: 0.0,
        cost: f64::NAN,
        sigma_px: 0.0,
        contrast_per_mm: contrast_per_mm(image, chords),
        chords: chords.to_vec(),
    })
}

/// The chords of `mesh` in `view`, moved outward by one of `offsets_mm` and blurred by one of
/// `sigmas_px`, that fit `image` best ([`fit_blur`]'s criterion, on the footprint of the widest
/// offset and blur, so that every candidate is judged on the same pixels); with no offset given,
/// the mesh as it is.
pub fn fit_mesh_projection(
    image: &Image,
    mesh: &TriMesh,
    view: &ConeBeamView,
    offsets_mm: &[f64],
    sigmas_px: &[f64],
) -> Result<MatchedChords> {
    let width = image.width as usize;
    let by_offset: Vec<(f64, Vec<f32>)> =
        offsets_mm.iter().map(|&o| Ok((o, mesh_chords(&mesh.offset(o), view)?))).collect::<Result<_>>()?;
    // Every candidate is judged on the footprint of the widest offset and blur.
    let Some((_, widest)) = by_offset.iter().max_by(|a, b| a.0.total_cmp(&b.0)) else {
        return Ok(fit_blur(image, &mesh_chords(mesh, view)?, sigmas_px));
    };
    let widest_sigma = sigmas_px.iter().copied().fold(0.0, f64::max);
    let pixels = footprint(widest, width, widest_sigma);
    let fits = by_offset.iter().map(|(offset_mm, chords)| MatchedChords {
        offset_mm: *offset_mm,
        ..fit_blur_on(image, chords, sigmas_px, &pixels)
    });
    let best = fits.reduce(|best, fit| if fit.cost < best.cost { fit } else { best });
    Ok(best.unwrap_or_else(|| fit_blur(image, widest, sigmas_px)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::masks::minus_solid;
    use crate::data::projector::mesh::tests::{box_mesh, view};

    /// A 40 × 40 chord image: a bar 10 px wide of 3 mm chords with rounded (parabolic) edges.
    fn bar() -> Vec<f32> {
        (0..40 * 40)
            .map(|i| {
                let x = (i % 40) as f64 - 19.5;
                (3.0 * (1.0 - (x / 5.0).powi(2))).max(0.0) as f32
            })
            .collect()
    }

    #[test]
    fn blur_keeps_the_sum_and_the_unknown_pixels() {
        let mut chords = bar();
        chords[5 * 40 + 20] = f32::NAN;
        let blurred = gaussian_blurred(&chords, 40, 1.0);
        assert!(blurred[5 * 40 + 20].is_nan());
        // Away from the borders and the NaN, a row's sum is kept (the bar runs along columns).
        let row = |v: &[f32], y: usize| v[y * 40..(y + 1) * 40].iter().map(|&x| x as f64).sum::<f64>();
        assert!((row(&blurred, 20) - row(&chords, 20)).abs() < 1e-3, "{} {}", row(&blurred, 20), row(&chords, 20));
        assert_eq!(gaussian_blurred(&chords, 40, 0.0)[..40], chords[..40]);
    }

    #[test]
    fn the_fitted_blur_removes_the_ring_that_sharp_chords_leave() {
        // The image: the bar blurred by 1 px at 2.5 units per mm, plus a faint vessel along row
        // 10 that crosses it (0.3 units).
        let chords = bar();
        let mut data: Vec<f32> = gaussian_blurred(&chords, 40, 1.0).iter().map(|&c| 2.5 * c).collect();
        (0..40).for_each(|x| data[10 * 40 + x] += 0.3);
        let image = Image { width: 40, height: 40, data };
        let fit = fit_blur(&image, &chords, &BLUR_SIGMAS_PX);
        assert_eq!(fit.sigma_px, 1.0);
        assert!((fit.contrast_per_mm - 2.5).abs() < 0.05, "{}", fit.contrast_per_mm);
        let ring =
            |rest: &Image| (0..40 * 40).filter(|i| i / 40 != 10).map(|i| rest.data[i].abs()).fold(0.0f32, f32::max);
        let sharp = minus_solid(&image, &chords, contrast_per_mm(&image, &chords));
        let matched = minus_solid(&image, &fit.chords, fit.contrast_per_mm);
        assert!(ring(&sharp) > 0.5, "sharp chords leave a ring of {}", ring(&sharp));
        assert!(ring(&matched) < 0.05, "the fitted blur leaves {}", ring(&matched));
        // The vessel behind the bar stays in the residual.
        assert!((matched.data[10 * 40 + 20] - 0.3).abs() < 0.05, "{}", matched.data[10 * 40 + 20]);
    }

    #[test]
    fn a_mesh_inside_the_imaged_solid_is_fitted_with_its_offset_and_blur() {
        let (lo, hi) = ([-7.3, -4.1, -5.2], [6.1, 3.9, 2.7]);
        let mesh = box_mesh(lo, hi);
        let view = view();
        let width = view.width() as usize;
        let imaged = mesh_chords(&mesh.offset(0.2), &view).unwrap();
        let data = gaussian_blurred(&imaged, width, 0.5).iter().map(|&c| 2.0 * c).collect();
        let image = Image { width: view.width(), height: view.height(), data };
        let fit = fit_mesh_projection(&image, &mesh, &view, &OFFSETS_MM, &BLUR_SIGMAS_PX).unwrap();
        assert_eq!((fit.offset_mm, fit.sigma_px), (0.2, 0.5), "{fit:?}");
        assert!((fit.contrast_per_mm - 2.0).abs() < 1e-3 && fit.cost < 1e-4, "{} {}", fit.contrast_per_mm, fit.cost);
        let sharp = fit_blur(&image, &mesh_chords(&mesh, &view).unwrap(), &[0.0]);
        assert!(sharp.cost > 100.0 * fit.cost.max(1e-6), "the mesh as it is fits worse: {}", sharp.cost);
    }
}
