//! Losses: `(1 − λ) L1 + λ (1 − SSIM)` on images normalised by the targets' maximum (SSIM from
//! `ctadsa_ops::ssim`), the false-negative loss over vessel pixels (the prior-anchoring term's
//! search is `ctadsa_ops::anchor_op`).

use burn::tensor::{Device, Int, Tensor, TensorData};

use ctadsa_ops::loss_op::l1_mean;
use ctadsa_ops::ssim::{SsimTarget, ssim_against};

use crate::data::case::images::Image;
use crate::data::vessel_evidence::VesselEvidence;

/// Everything about the targets that the losses need, computed once.
#[derive(Debug, Clone)]
pub struct LossTargets {
    /// `[V, H, W]` targets in image units.
    pub target: Tensor<3>,
    /// Normalisation of L1/SSIM: images are multiplied by `1 / max(target)`.
    pub scale: f32,
    /// Per view `[V, 1, 1]`: the FN normaliser `c` (the view's bright value,
    /// [`VesselEvidence::bright`]: the 99.5th percentile of the pixels that show something).
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
        for (img, evidence) in images.iter().zip(VesselEvidence::of_views(images)) {
            target.extend_from_slice(&img.data);
            // g: the image over the view's bright value; vessel pixels: the view's vessel evidence
            // at its level at τ (g ≥ τ, and clear of the view's noise).
            let c = evidence.bright().unwrap_or(max as f64) as f32;
            cs.push(c);
            let g: Vec<f32> = img.data.iter().map(|&x| (x / c).clamp(0.0, 1.0)).collect();
            let level = evidence.level(tau);
            let mask: Vec<f32> = (evidence.image.data.iter().enumerate())
                .map(|(i, &x)| (x as f64 >= level && x > 0.0 && evidence.settled_at(i)) as u8 as f32)
                .collect();
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

    /// L1 and SSIM (`[1]` each) of `pred` against the targets, both images normalised; the
    /// total is [`ctadsa_ops::loss_op::total_loss`].
    pub fn image_terms(&self, pred: Tensor<3>) -> (Tensor<1>, Tensor<1>) {
        let p = pred.mul_scalar(self.scale);
        // The SSIM statistics' target is the normalised target (`target · scale`).
        let l1v = l1_mean(p.clone(), self.ssim_target.y.clone());
        let s = ssim_against(p, &self.ssim_target);
        (l1v, s)
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

    #[test]
    fn l1_by_hand() {
        let t = |v: f32| Tensor::<3>::from_data(TensorData::new(vec![v; 6], [1, 2, 3]), &dev());
        assert_eq!(l1_mean(t(0.0), t(1.0)).into_scalar::<f32>(), 1.0);
    }

    #[test]
    fn fn_loss_by_hand() {
        // One view, 1 × 8 pixels, a single positive pixel on a flat (noise-free) background:
        // c = 2, g = [0, 0, 1, 0, …], the only vessel pixel has all the weight.
        let img = Image { width: 8, height: 1, data: vec![0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0] };
        let t = LossTargets::new(&[img], 0.01, &dev());
        let pred =
            Tensor::<3>::from_data(TensorData::new(vec![5.0f32, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0], [1, 1, 8]), &dev());
        // miss = relu(1 − 0.25 − 0.005) = 0.745.
        let l = t.fn_loss(pred, 0.005).into_scalar::<f32>();
        assert!((l - 0.745).abs() < 1e-6, "{l}");
    }
}
