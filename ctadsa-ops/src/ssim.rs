//! SSIM between `[V, H, W]` image stacks as a loss: the 11 × 11 Gaussian window (σ = 1.5 px,
//! zero padding) of [`crate::blur_op`], the target's statistics computed once
//! ([`SsimTarget`]) and the rest one backend op ([`crate::ssim_op`]); the same written with plain
//! tensor operations as the ops' test oracles.

use burn::tensor::{Int, Tensor};

/// Separable 11 × 11 Gaussian blur (σ = 1.5 px) of `[V, H, W]` images with zero padding: the
/// SSIM window, one backend op ([`crate::blur_op`]).
pub fn gaussian_blur(x: Tensor<3>) -> Tensor<3> {
    crate::blur_op::window_blur(x)
}

/// The same blur as shifted slices of plain tensor operations (autodiff through them): the
/// op's test oracle.
pub fn gaussian_blur_sliced(x: Tensor<3>) -> Tensor<3> {
    let taps = crate::blur_op::taps();
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
/// one backend op ([`crate::ssim_op`]).
pub fn ssim_against(pred: Tensor<3>, target: &SsimTarget) -> Tensor<1> {
    crate::ssim_op::ssim_mean(pred, target.y.clone(), target.mu_y.clone(), target.syy.clone())
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

#[cfg(test)]
mod tests {
    use burn::tensor::{Device, TensorData};

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
    }
}
