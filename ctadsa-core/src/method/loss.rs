//! Losses: `(1 − λ) L1 + λ (1 − SSIM)` on images normalised by the targets' maximum, the
//! false-negative loss over vessel pixels, and the prior-anchoring term.

use burn::tensor::{Device, Int, Tensor, TensorData};
use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::data::case::images::Image;
use crate::stats::percentile;

/// Separable 11 × 11 Gaussian blur (σ = 1.5 px) of `[V, H, W]` images with zero padding: the
/// SSIM window, one backend op ([`crate::method::blur_op`]).
pub fn gaussian_blur(x: Tensor<3>) -> Tensor<3> {
    crate::method::blur_op::window_blur(x)
}

/// The same blur as shifted slices of plain tensor operations (autodiff through them): the
/// op's test oracle.
pub fn gaussian_blur_sliced(x: Tensor<3>) -> Tensor<3> {
    let taps = crate::method::blur_op::taps();
    let [v, h, w] = x.dims();
    let device = x.device();
    let zw = Tensor::<3>::zeros([v, h, 5], &device);
    let xp = Tensor::cat(vec![zw.clone(), x, zw], 2);
    let mut along_w = xp.clone().slice([0..v, 0..h, 0..w]).mul_scalar(taps[0]);
    for (k, &t) in taps.iter().enumerate().skip(1) {
        along_w = along_w + xp.clone().slice([0..v, 0..h, k..k + w]).mul_scalar(t);
    }
    let zh = Tensor::<3>::zeros([v, 5, w], &device);
    let yp = Tensor::cat(vec![zh.clone(), along_w, zh], 1);
    let mut out = yp.clone().slice([0..v, 0..h, 0..w]).mul_scalar(taps[0]);
    for (k, &t) in taps.iter().enumerate().skip(1) {
        out = out + yp.clone().slice([0..v, k..k + h, 0..w]).mul_scalar(t);
    }
    out
}

/// Mean SSIM of `[V, H, W]` images (Wang et al.; 11 × 11 Gaussian window σ 1.5, zero padding,
/// C1 = 0.01², C2 = 0.03², i.e. images expected in [0, 1]), averaged over all pixels and views.
pub fn ssim(pred: Tensor<3>, target: Tensor<3>) -> Tensor<1> {
    let stats = SsimTarget::new(target);
    ssim_against(pred, &stats)
}

/// The target's side of SSIM (its windowed mean and variance), computed once per target.
#[derive(Debug, Clone)]
pub struct SsimTarget {
    /// `[V, H, W]` target.
    pub y: Tensor<3>,
    /// Windowed mean of the target.
    pub mu_y: Tensor<3>,
    /// Windowed variance of the target.
    pub syy: Tensor<3>,
}

impl SsimTarget {
    /// Blurs the target's mean and variance.
    pub fn new(y: Tensor<3>) -> Self {
        let mu_y = gaussian_blur(y.clone());
        let syy = gaussian_blur(y.clone() * y.clone()) - mu_y.clone() * mu_y.clone();
        Self { y, mu_y, syy }
    }

    /// The same for a subset of views.
    pub fn select(&self, views: Tensor<1, Int>) -> Self {
        Self {
            y: self.y.clone().select(0, views.clone()),
            mu_y: self.mu_y.clone().select(0, views.clone()),
            syy: self.syy.clone().select(0, views),
        }
    }
}

/// [`ssim`] against a target whose statistics are already known (3 blurs per call instead of 5):
/// one backend op ([`crate::method::ssim_op`]).
pub fn ssim_against(pred: Tensor<3>, target: &SsimTarget) -> Tensor<1> {
    crate::method::ssim_op::ssim_mean(pred, target.y.clone(), target.mu_y.clone(), target.syy.clone())
}

/// [`ssim_against`] written with plain tensor operations (autodiff through them): the op's test
/// oracle.
pub fn ssim_against_composed(pred: Tensor<3>, target: &SsimTarget) -> Tensor<1> {
    let (x, y) = (pred, target.y.clone());
    let mu_x = gaussian_blur(x.clone());
    let mu_y = target.mu_y.clone();
    let sxx = gaussian_blur(x.clone() * x.clone()) - mu_x.clone() * mu_x.clone();
    let syy = target.syy.clone();
    let sxy = gaussian_blur(x * y) - mu_x.clone() * mu_y.clone();
    let (c1, c2) = (0.01f32 * 0.01, 0.03f32 * 0.03);
    let num = (mu_x.clone() * mu_y.clone()).mul_scalar(2.0).add_scalar(c1) * sxy.mul_scalar(2.0).add_scalar(c2);
    let den = (mu_x.clone() * mu_x + mu_y.clone() * mu_y).add_scalar(c1) * (sxx + syy).add_scalar(c2);
    (num / den).mean()
}

/// Mean absolute difference.
pub fn l1(pred: Tensor<3>, target: Tensor<3>) -> Tensor<1> {
    (pred - target).abs().mean()
}

/// Everything about the targets that the losses need, computed once.
#[derive(Debug, Clone)]
pub struct LossTargets {
    /// `[V, H, W]` targets in image units.
    pub target: Tensor<3>,
    /// Normalisation of L1/SSIM: images are multiplied by `1 / max(target)`.
    pub scale: f32,
    /// Per view `[V, 1, 1]`: the FN normaliser `c` (99.5th percentile of positive pixels).
    pub fn_c: Tensor<3>,
    /// `[V, H, W]`: `clamp(target / c, 0, 1)`.
    pub fn_g: Tensor<3>,
    /// `[V, H, W]`: vessel mask × length-balancing weight, normalised to sum 1 per view.
    pub fn_weight: Tensor<3>,
    /// The normalised target's SSIM statistics.
    pub ssim_target: SsimTarget,
}

/// 15 × 15 box average with zero padding (host).
fn box_average(mask: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let mut tmp = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
            tmp[y * w + x] = mask[y * w + x0..=y * w + x1].iter().sum();
        }
    }
    let n = ((2 * r + 1) * (2 * r + 1)) as f32;
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
            out[y * w + x] = (y0..=y1).map(|yy| tmp[yy * w + x]).sum::<f32>() / n;
        }
    }
    out
}

impl LossTargets {
    /// Prepares the targets; `tau` selects vessel pixels (`g ≥ τ`).
    pub fn new(images: &[Image], tau: f64, device: &Device) -> Self {
        let (w, h) = (images[0].width as usize, images[0].height as usize);
        let v = images.len();
        let max = images.iter().map(Image::max).fold(0.0f32, f32::max).max(1e-12);
        let mut target = Vec::with_capacity(v * w * h);
        let mut cs = Vec::with_capacity(v);
        let mut gs = Vec::with_capacity(v * w * h);
        let mut weights = Vec::with_capacity(v * w * h);
        for img in images {
            target.extend_from_slice(&img.data);
            let pos: Vec<f64> = img.data.iter().filter(|&&x| x > 0.0).map(|&x| x as f64).collect();
            let c = if pos.is_empty() { max as f64 } else { percentile(&pos, 99.5) } as f32;
            cs.push(c);
            let g: Vec<f32> = img.data.iter().map(|&x| (x / c).clamp(0.0, 1.0)).collect();
            let mask: Vec<f32> = g.iter().map(|&x| (x as f64 >= tau && x > 0.0) as u8 as f32).collect();
            let density = box_average(&mask, w, h, 7);
            let wmap: Vec<f32> =
                mask.iter().zip(&density).map(|(&m, &d)| m * d.max(1e-4).powf(-0.25).min(3.0)).collect();
            let total: f32 = wmap.iter().sum::<f32>().max(1e-6);
            weights.extend(wmap.iter().map(|x| x / total));
            gs.extend(g);
        }
        let target = Tensor::from_data(TensorData::new(target, [v, h, w]), device);
        Self {
            ssim_target: SsimTarget::new(target.clone().mul_scalar(1.0 / max)),
            target,
            scale: 1.0 / max,
            fn_c: Tensor::from_data(TensorData::new(cs, [v, 1, 1]), device),
            fn_g: Tensor::from_data(TensorData::new(gs, [v, h, w]), device),
            fn_weight: Tensor::from_data(TensorData::new(weights, [v, h, w]), device),
        }
    }

    /// The same for a subset of views.
    pub fn select(&self, views: Tensor<1, Int>) -> Self {
        Self {
            target: self.target.clone().select(0, views.clone()),
            scale: self.scale,
            fn_c: self.fn_c.clone().select(0, views.clone()),
            fn_g: self.fn_g.clone().select(0, views.clone()),
            fn_weight: self.fn_weight.clone().select(0, views.clone()),
            ssim_target: self.ssim_target.select(views),
        }
    }

    /// `(1 − λ) L1 + λ (1 − SSIM)` on normalised images.
    pub fn render_loss(&self, pred: Tensor<3>, lambda_dssim: f64) -> (Tensor<1>, Tensor<1>, Tensor<1>) {
        let p = pred.mul_scalar(self.scale);
        let t = self.target.clone().mul_scalar(self.scale);
        let l1v = l1(p.clone(), t);
        let s = ssim_against(p, &self.ssim_target);
        let total =
            l1v.clone().mul_scalar(1.0 - lambda_dssim) + s.clone().neg().add_scalar(1.0).mul_scalar(lambda_dssim);
        (total, l1v, s)
    }

    /// The false-negative loss, averaged over views:
    /// `Σ weight · relu(g − clamp(pred/c, 0, 1) − margin)`.
    pub fn fn_loss(&self, pred: Tensor<3>, margin: f64) -> Tensor<1> {
        let v = pred.dims()[0] as f32;
        let r = (pred / self.fn_c.clone()).clamp(0.0, 1.0);
        let miss = burn::tensor::activation::relu((self.fn_g.clone() - r).sub_scalar(margin));
        (self.fn_weight.clone() * miss).sum().div_scalar(v)
    }
}

/// Prior anchoring: Gaussians within `radius` of the prior surface are pulled to the mean of
/// their `k` nearest prior-surface points.
pub struct PriorAnchor {
    points: Vec<[f64; 3]>,
    tree: ImmutableKdTree<f64, 3>,
    /// Where a centre may have a prior point within the radius (rejects the others without a
    /// tree search).
    near: NearCells,
    pub radius_mm: f64,
    pub k: usize,
}

impl PriorAnchor {
    /// From prior-surface points (mm).
    pub fn new(points: &[DVec3], radius_mm: f64, k: usize) -> Option<Self> {
        if points.is_empty() {
            return None;
        }
        let pts: Vec<[f64; 3]> = points.iter().map(|p| p.to_array()).collect();
        let tree = ImmutableKdTree::new_from_slice(&pts).ok()?;
        let near = NearCells::new(&pts, radius_mm);
        Some(Self { points: pts, tree, near, radius_mm, k })
    }

    /// For centres `[n·3]` (host), the anchored ones: their positions in the slice and targets.
    pub fn targets(&self, centres: &[f32]) -> (Vec<usize>, Vec<f32>) {
        let k = std::num::NonZero::new(self.k.max(1)).expect("k ≥ 1");
        let queries: Vec<[f64; 3]> = centres.chunks_exact(3).map(|c| [c[0] as f64, c[1] as f64, c[2] as f64]).collect();
        let r2 = self.radius_mm * self.radius_mm;
        // Only centres with a prior point in a neighbouring cell can be within r.
        let near: Vec<usize> = (0..queries.len()).filter(|&i| self.near.may_be_near(queries[i])).collect();
        let near_queries: Vec<[f64; 3]> = near.iter().map(|&i| queries[i]).collect();
        let knn = self.tree.query_batch(&near_queries).nearest_n::<SquaredEuclidean<f64>>(k).execute();
        let results: Vec<(usize, &[_])> = near.iter().copied().zip(knn.iter()).collect();
        let mut idx = Vec::new();
        let mut tgt = Vec::new();
        for &(i, res) in &results {
            if res.first().is_some_and(|n| n.distance <= r2) {
                let mut m = [0.0f64; 3];
                for n in res.iter() {
                    let p = self.points[n.item as usize];
                    for a in 0..3 {
                        m[a] += p[a] / res.len() as f64;
                    }
                }
                idx.push(i);
                tgt.extend(m.map(|v| v as f32));
            }
        }
        (idx, tgt)
    }
}

/// A bit per cell of a grid of cells at least the radius wide: set where the cell or one of its
/// 26 neighbours holds a point, so that a query whose cell is unset has no point within the
/// radius.
struct NearCells {
    origin: [f64; 3],
    cell_mm: f64,
    dims: [usize; 3],
    bits: Vec<u64>,
}

impl NearCells {
    /// At most this many cells along an axis (the cells widen beyond the radius for large
    /// extents).
    const MAX_DIM: usize = 512;

    fn new(points: &[[f64; 3]], radius_mm: f64) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        // A hair wider than the radius, so that rounding of the cell index cannot put a point
        // at exactly the radius two cells away.
        let cell_mm = (radius_mm * 1.001).max(extent / (Self::MAX_DIM - 4) as f64).max(1e-6);
        // One empty cell of margin on each side, so that every neighbour of a point's cell exists.
        let origin = lo.map(|l| l - cell_mm);
        let dims = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / cell_mm).floor() as usize + 3).min(Self::MAX_DIM));
        let mut cells = Self { origin, cell_mm, dims, bits: vec![0; (dims[0] * dims[1] * dims[2]).div_ceil(64)] };
        for p in points {
            let Some(c) = cells.cell(*p) else { continue };
            for dz in 0..3 {
                for dy in 0..3 {
                    for dx in 0..3 {
                        let i = (c[0] + dx - 1) + dims[0] * ((c[1] + dy - 1) + dims[1] * (c[2] + dz - 1));
                        cells.bits[i / 64] |= 1 << (i % 64);
                    }
                }
            }
        }
        cells
    }

    /// The cell holding `p`, when it lies inside the grid (points always do).
    fn cell(&self, p: [f64; 3]) -> Option<[usize; 3]> {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let t = ((p[a] - self.origin[a]) / self.cell_mm).floor();
            if !(t >= 1.0 && t < (self.dims[a] - 1) as f64) {
                return None;
            }
            c[a] = t as usize;
        }
        Some(c)
    }

    /// Whether a point may lie within the radius of `q` (false: certainly none does).
    fn may_be_near(&self, q: [f64; 3]) -> bool {
        let mut c = [0usize; 3];
        for a in 0..3 {
            let t = ((q[a] - self.origin[a]) / self.cell_mm).floor();
            // Outside the grid: more than one cell (≥ the radius) from every point.
            if !(t >= 0.0 && t < self.dims[a] as f64) {
                return false;
            }
            c[a] = t as usize;
        }
        let i = c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2]);
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(deprecated)]
    fn dev() -> Device {
        Device::ndarray()
    }

    /// Direct f64 SSIM with the same window, zero padding and constants.
    fn ssim_reference(x: &[f64], y: &[f64], w: usize, h: usize) -> f64 {
        let g: Vec<f64> = (0..11).map(|i| (-((i as f64 - 5.0).powi(2)) / 4.5).exp()).collect();
        let s: f64 = g.iter().sum();
        let at = |img: &[f64], r: i64, c: i64| {
            if r < 0 || c < 0 || r >= h as i64 || c >= w as i64 { 0.0 } else { img[r as usize * w + c as usize] }
        };
        let mut total = 0.0;
        for r in 0..h as i64 {
            for c in 0..w as i64 {
                let (mut mx, mut my, mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for a in 0..11i64 {
                    for b in 0..11i64 {
                        let k = g[a as usize] * g[b as usize] / (s * s);
                        let (p, q) = (at(x, r + a - 5, c + b - 5), at(y, r + a - 5, c + b - 5));
                        mx += k * p;
                        my += k * q;
                        xx += k * p * p;
                        yy += k * q * q;
                        xy += k * p * q;
                    }
                }
                let (c1, c2) = (1e-4, 9e-4);
                total += ((2.0 * mx * my + c1) * (2.0 * (xy - mx * my) + c2))
                    / ((mx * mx + my * my + c1) * ((xx - mx * mx) + (yy - my * my) + c2));
            }
        }
        total / (w * h) as f64
    }

    #[test]
    fn ssim_matches_a_direct_evaluation_and_is_one_for_equal_images() {
        let (w, h) = (23, 17);
        let x: Vec<f64> = (0..w * h).map(|i| (i * 37 % 101) as f64 / 100.0).collect();
        let y: Vec<f64> =
            x.iter().enumerate().map(|(i, v)| (v * 0.7 + 0.2 * ((i % 7) as f64 / 7.0)).min(1.0)).collect();
        let t = |v: &Vec<f64>| {
            Tensor::<3>::from_data(TensorData::new(v.iter().map(|&a| a as f32).collect::<Vec<_>>(), [1, h, w]), &dev())
        };
        let ours = ssim(t(&x), t(&y)).into_scalar::<f32>() as f64;
        let reference = ssim_reference(&x, &y, w, h);
        assert!((ours - reference).abs() < 1e-5, "{ours} vs {reference}");
        let same = ssim(t(&x), t(&x)).into_scalar::<f32>() as f64;
        assert!((same - 1.0).abs() < 1e-5, "{same}");
        // Hand-checked values: equal images → 1; L1 of 0 vs 1 → 1.
        let l = l1(t(&vec![0.0; w * h]), t(&vec![1.0; w * h])).into_scalar::<f32>();
        assert_eq!(l, 1.0);
    }

    #[test]
    fn fn_loss_by_hand() {
        // One view, 1 × 4 pixels: target [0, 1, 2, 4] → c = P99.5 of {1, 2, 4} = 3.98,
        // but use an exactly known case: a single positive pixel.
        let img = Image { width: 4, height: 1, data: vec![0.0, 0.0, 2.0, 0.0] };
        let t = LossTargets::new(&[img], 0.01, &dev());
        // c = 2, g = [0, 0, 1, 0], the only vessel pixel has all the weight.
        let pred = Tensor::<3>::from_data(TensorData::new(vec![5.0f32, 0.0, 0.5, 0.0], [1, 1, 4]), &dev());
        // miss = relu(1 − 0.25 − 0.005) = 0.745.
        let l = t.fn_loss(pred, 0.005).into_scalar::<f32>();
        assert!((l - 0.745).abs() < 1e-6, "{l}");
    }

    #[test]
    fn anchoring_targets_are_means_of_nearest_points() {
        let pts: Vec<DVec3> = (0..10).map(|i| DVec3::new(i as f64, 0.0, 0.0)).collect();
        let a = PriorAnchor::new(&pts, 0.5, 2).unwrap();
        let (idx, tgt) = a.targets(&[4.2, 0.3, 0.0, 4.5, 3.0, 0.0]);
        assert_eq!(idx, vec![0]); // the second centre is 3 mm away
        assert_eq!(tgt, vec![4.5, 0.0, 0.0]); // mean of points 4 and 5
    }

    /// The cell pre-test rejects nothing that a brute-force search keeps: targets equal the
    /// mean of the k nearest points for exactly the centres within the radius.
    #[test]
    fn anchoring_matches_a_brute_force_search() {
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        // Points on a sphere of radius 5 mm; centres in a shell around it.
        let pts: Vec<DVec3> = (0..3000)
            .map(|_| {
                let d = DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5).normalize_or(DVec3::X);
                d * 5.0 + DVec3::new(1.0, -2.0, 3.0)
            })
            .collect();
        let (radius, k) = (0.4, 4);
        let a = PriorAnchor::new(&pts, radius, k).unwrap();
        let centres: Vec<f32> = (0..1500)
            .flat_map(|_| {
                let d = DVec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5).normalize_or(DVec3::X);
                let p = d * (4.0 + 2.0 * uniform()) + DVec3::new(1.0, -2.0, 3.0);
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect();
        let (idx, tgt) = a.targets(&centres);
        let mut expected = Vec::new();
        for (i, c) in centres.chunks_exact(3).enumerate() {
            let q = DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64);
            let mut d: Vec<(f64, DVec3)> = pts.iter().map(|p| (p.distance_squared(q), *p)).collect();
            d.sort_by(|x, y| x.0.total_cmp(&y.0));
            if d[0].0 <= radius * radius {
                let mean = d[..k].iter().map(|x| x.1).sum::<DVec3>() / k as f64;
                expected.push((i, mean));
            }
        }
        assert!(expected.len() > 100 && expected.len() < 1400, "{} centres near", expected.len());
        assert_eq!(idx, expected.iter().map(|e| e.0).collect::<Vec<_>>());
        for (j, (_, m)) in expected.iter().enumerate() {
            let t = DVec3::new(tgt[3 * j] as f64, tgt[3 * j + 1] as f64, tgt[3 * j + 2] as f64);
            assert!(t.distance(*m) < 1e-5, "{t} vs {m}");
        }
    }
}
