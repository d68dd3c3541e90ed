//! The SSIM window — a separable 11-tap Gaussian blur of `[V, H, W]` images with zero padding —
//! as one burn backend op. The blur is linear and, with a symmetric kernel and zero padding,
//! its own adjoint, so the backward is the same blur of the upstream gradient. Written as
//! shifted slices (the form `ssim::gaussian_blur_sliced` keeps as the test oracle) it made
//! 22 slice, cat and add nodes per call, about half of the quick configuration's step.

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

pub mod cpu;
#[cfg(feature = "wgpu")]
pub(crate) mod gpu;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{Autodiff, Backend, Dispatch, NdArray, TensorMetadata, backend_extension, tensor::FloatTensor};
use burn::tensor::{Tensor, TensorData};

use crate::ndarray_host::with_host;

/// The window's taps: a Gaussian of σ = 1.5 px, normalised to sum 1.
pub fn taps() -> [f32; 2 * cpu::RADIUS + 1] {
    let g: Vec<f64> = (0..11).map(|i| (-((i as f64 - 5.0).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
    let s: f64 = g.iter().sum();
    std::array::from_fn(|i| (g[i] / s) as f32)
}

/// Backend operation of the blur.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait BlurBackend: Backend {
    /// `[V, H, W]` → `[V, H, W]`, blurred along W then H with zero padding.
    fn window_blur(images: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl BlurBackend for NdArray {
    fn window_blur(images: FloatTensor<Self>) -> FloatTensor<Self> {
        let shape = images.shape();
        let [v, h, w] = [shape[0], shape[1], shape[2]];
        let out = with_host(&images, |x| cpu::blur(x, v, h, w, &taps()));
        Self::float_from_data(TensorData::new(out, [v, h, w]), &images.device())
    }
}

#[cfg(feature = "wgpu")]
impl BlurBackend for burn_cubecl::CubeBackend {
    fn window_blur(images: FloatTensor<Self>) -> FloatTensor<Self> {
        gpu::blur(images)
    }
}

#[derive(Debug)]
struct BlurBackward;

impl<B: Backend + BlurBackend> Backward<B, 1> for BlurBackward {
    type State = ();

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node] = ops.parents;
        let grad = grads.consume::<B>(&ops.node);
        if let Some(n) = node {
            grads.register::<B>(n.id, B::window_blur(grad));
        }
    }
}

impl<B: Backend + BlurBackend, C: CheckpointStrategy> BlurBackend for Autodiff<B, C> {
    fn window_blur(images: FloatTensor<Self>) -> FloatTensor<Self> {
        let prep = BlurBackward.prepare::<C>([images.node()]).compute_bound();
        prep.stateless(B::window_blur(images.into_primitive()))
    }
}

/// The SSIM window blur of `[V, H, W]` images (differentiable).
pub fn window_blur(images: Tensor<3>) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as BlurBackend>::window_blur(images.into_dispatch()))
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Device, Distribution};

    use super::*;
    use crate::readback::host_vec;
    use crate::ssim::gaussian_blur_sliced;

    /// The op against the shifted-slice form, forward and backward (autodiff through the
    /// slices), on images smaller and larger than the window.
    #[test]
    fn blur_op_matches_the_sliced_blur_forward_and_backward() {
        let device = Device::ndarray().autodiff();
        for [v, h, w] in [[2, 7, 4], [3, 23, 31]] {
            let x = Tensor::<3>::random([v, h, w], Distribution::Uniform(-1.0, 1.0), &device).require_grad();
            let up = Tensor::<3>::random([v, h, w], Distribution::Uniform(-1.0, 1.0), &device);
            let (ours, sliced) = (window_blur(x.clone()), gaussian_blur_sliced(x.clone()));
            let (a, b) = (host_vec(ours.clone()), host_vec(sliced.clone()));
            let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "[{v}, {h}, {w}] forward: worst difference {worst}");
            let ga = x.grad(&(ours * up.clone()).sum().backward()).unwrap();
            let gb = x.grad(&(sliced * up).sum().backward()).unwrap();
            let (a, b) = (host_vec(ga), host_vec(gb));
            let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "[{v}, {h}, {w}] backward: worst difference {worst}");
        }
    }

    /// A constant image far from the border keeps its value (the taps sum to 1), and an impulse
    /// spreads into the outer product of the taps.
    /// The GPU kernels' taps are the CPU kernels' to the last bit.
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_gpu_taps_are_the_window() {
        assert_eq!(gpu::HALF_TAPS.as_slice(), &taps()[5..]);
    }

    /// The kernel sums each output's taps in tap order, as the plain per-pixel loop does: the
    /// same bits, with rows narrower than the window, as wide and wider.
    #[test]
    fn blur_kernel_is_the_per_pixel_sum_to_the_bit() {
        let t = taps();
        let plain = |x: &[f32], h: usize, w: usize| -> Vec<f32> {
            let at = |r: i64, c: i64| {
                if (0..h as i64).contains(&r) && (0..w as i64).contains(&c) {
                    Some(x[r as usize * w + c as usize])
                } else {
                    None
                }
            };
            let mut rows = vec![0.0f32; h * w];
            for r in 0..h {
                for c in 0..w {
                    let mut acc = 0.0f32;
                    for (k, tk) in t.iter().enumerate() {
                        if let Some(v) = at(r as i64, c as i64 + k as i64 - 5) {
                            acc += tk * v;
                        }
                    }
                    rows[r * w + c] = acc;
                }
            }
            let mut out = vec![0.0f32; h * w];
            for r in 0..h {
                for c in 0..w {
                    let mut acc = 0.0f32;
                    for (k, tk) in t.iter().enumerate() {
                        let rr = r as i64 + k as i64 - 5;
                        if (0..h as i64).contains(&rr) {
                            acc += tk * rows[rr as usize * w + c];
                        }
                    }
                    out[r * w + c] = acc;
                }
            }
            out
        };
        for (h, w) in [(3, 2), (6, 11), (9, 12), (13, 37)] {
            let x: Vec<f32> = (0..h * w).map(|i| ((i * 7919 % 1000) as f32 / 250.0 - 2.0).sin()).collect();
            assert_eq!(cpu::blur(&x, 1, h, w, &t), plain(&x, h, w), "{h} × {w}");
        }
    }

    #[test]
    fn blur_of_an_impulse_is_the_window() {
        let (h, w) = (15, 17);
        let mut x = vec![0.0f32; h * w];
        x[7 * w + 8] = 1.0;
        let out = cpu::blur(&x, 1, h, w, &taps());
        let t = taps();
        for r in 0..h {
            for c in 0..w {
                let (dr, dc) = (r as i64 - 7 + 5, c as i64 - 8 + 5);
                let expected =
                    if (0..11).contains(&dr) && (0..11).contains(&dc) { t[dr as usize] * t[dc as usize] } else { 0.0 };
                assert!((out[r * w + c] - expected).abs() < 1e-7, "({r}, {c})");
            }
        }
        assert!((t.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }
}
