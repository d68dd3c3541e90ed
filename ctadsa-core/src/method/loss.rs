//! Losses: `(1 − λ) L1 + λ (1 − SSIM)` on images normalised by the targets' maximum, the
//! false-negative loss over vessel pixels (the prior-anchoring term's search is `anchor_op`).

use burn::tensor::{Device, Int, Tensor, TensorData};

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
}
