//! Gradients of the render op (CPU backend, autodiff) against central finite differences of the
//! f64 closed-form line integral, for means, scales, rotations and densities, and the
//! densification statistic against its definition.
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

mod common;

use burn::tensor::{Device, Tensor, TensorData};
use common::*;
use ctadsa_render::reference::{RefGaussian, line_integral_exact, ray_mahalanobis2};
use ctadsa_render::{ConeBeamView, Gaussians, RenderSettings, ViewSet, render, render_with_stats};

/// `L = Σ_pixels weight · image` in f64 from the reference closed form; a Gaussian counts for a
/// pixel whose ray meets its `k`-σ ellipsoid, as in the renderer.
fn loss_f64(gs: &[RefGaussian], views: &ViewSet, weights: &[f64], k: f64) -> f64 {
    let (w, h) = views.image_size();
    let mut total = 0.0;
    let mut i = 0;
    for view in views.views() {
        for r in 0..h {
            for c in 0..w {
                let d = view.pixel_ray(c as f64, r as f64);
                let o = view.source_mm();
                let v: f64 = gs
                    .iter()
                    .filter(|g| ray_mahalanobis2(g, o, d) <= k * k)
                    .map(|g| line_integral_exact(g, o, d))
                    .sum();
                total += weights[i] * v;
                i += 1;
            }
        }
    }
    total
}

/// Finite-difference gradient of every parameter, in the order means, scales, quats, densities.
fn fd_gradients(gs: &[RefGaussian], views: &ViewSet, weights: &[f64], k: f64) -> [Vec<f64>; 4] {
    let mut out: [Vec<f64>; 4] = Default::default();
    for (gi, g) in gs.iter().enumerate() {
        let eval = |m: &dyn Fn(&mut RefGaussian)| {
            let mut copy = gs.to_vec();
            m(&mut copy[gi]);
            loss_f64(&copy, views, weights, k)
        };
        for k in 0..3 {
            let h = 1e-5;
            out[0].push((eval(&|g| g.mean[k] += h) - eval(&|g| g.mean[k] -= h)) / (2.0 * h));
        }
        for k in 0..3 {
            let h = 1e-6 * g.scale[k];
            out[1].push((eval(&|g| g.scale[k] += h) - eval(&|g| g.scale[k] -= h)) / (2.0 * h));
        }
        for k in 0..4 {
            let h = 1e-6;
            out[2].push((eval(&|g| g.quat[k] += h) - eval(&|g| g.quat[k] -= h)) / (2.0 * h));
        }
        let h = 1e-6;
        out[3].push((eval(&|g| g.density += h) - eval(&|g| g.density -= h)) / (2.0 * h));
    }
    out
}

fn scene() -> (Vec<RefGaussian>, ViewSet) {
    let mut rng = Rng(42);
    let gs = random_gaussians(&mut rng, 4, 8.0, (0.8, 3.0));
    let views =
        view_set(&[small_geometry(-90.0, 40, 1.0), small_geometry(0.0, 40, 1.0), small_geometry(-40.0, 40, 1.0)]);
    (gs, views)
}

fn params(g: &Gaussians) -> Gaussians {
    Gaussians {
        means: g.means.clone().require_grad(),
        scales: g.scales.clone().require_grad(),
        rotations: g.rotations.clone().require_grad(),
        densities: g.densities.clone().require_grad(),
    }
}

#[test]
fn gradients_match_finite_differences() {
    gradients_match_finite_differences_at(6.0);
}

/// At the default footprint cut-off the render is the truncated sum; its gradient is the
/// truncated sum's (pixels do not cross the cut-off under the finite-difference steps).
#[test]
fn gradients_match_finite_differences_at_the_default_cutoff() {
    gradients_match_finite_differences_at(3.0);
}

fn gradients_match_finite_differences_at(k: f32) {
    let (gs, views) = scene();
    let device = Device::ndarray().autodiff();
    let (w, h) = views.image_size();
    let n_px = views.len() * (w * h) as usize;
    let mut rng = Rng(3);
    let weights: Vec<f64> = (0..n_px).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let g = params(&to_tensors(&gs, &device));
    let img = render(&g, &views, &RenderSettings { k_sigma: k, ..Default::default() }).unwrap();
    let wt = Tensor::<3>::from_data(
        TensorData::new(weights.iter().map(|&x| x as f32).collect::<Vec<_>>(), [views.len(), h as usize, w as usize]),
        &device,
    );
    let grads = (img * wt).sum().backward();
    let ours = [
        to_vec(g.means.grad(&grads).unwrap()),
        to_vec(g.scales.grad(&grads).unwrap()),
        to_vec(g.rotations.grad(&grads).unwrap()),
        to_vec(g.densities.grad(&grads).unwrap()),
    ];
    let fd = fd_gradients(&gs, &views, &weights, k as f64);
    for (name, (a, b)) in ["means", "scales", "rotations", "densities"].iter().zip(ours.iter().zip(fd.iter())) {
        let a: Vec<f64> = a.iter().map(|&x| x as f64).collect();
        let err = rel_l2(&a, b);
        println!(
            "k = {k}, {name}: relative L2 error {err:.2e} (|fd| = {:.3e})",
            b.iter().map(|x| x * x).sum::<f64>().sqrt()
        );
        assert!(err < 1e-3, "{name}: ours {a:?}\n fd {b:?}");
    }
}

#[test]
fn screen_statistic_is_the_ndc_gradient_of_the_projected_centre() {
    let (gs, _) = scene();
    let geom = small_geometry(-30.0, 40, 1.0);
    let views = view_set(&[geom]);
    let view = ConeBeamView::from_tigre(&geom).unwrap();
    let device = Device::ndarray().autodiff();
    let g = params(&to_tensors(&gs, &device));
    let probe = Tensor::<2>::zeros([gs.len(), 2], &device).require_grad();
    let img = render_with_stats(&g, probe.clone(), &views, &RenderSettings::default()).unwrap();
    let mut rng = Rng(11);
    let wt: Vec<f32> = (0..40 * 40).map(|_| rng.uniform(0.0, 1.0) as f32).collect();
    let wt = Tensor::<3>::from_data(TensorData::new(wt, [1, 40, 40]), &device);
    let grads = (img * wt).sum().backward();
    let d_mean = to_vec(g.means.grad(&grads).unwrap());
    let stats = to_vec(probe.grad(&grads).unwrap());
    let intr = view.intrinsics();
    for (i, gauss) in gs.iter().enumerate() {
        let dw = glam::DVec3::new(d_mean[3 * i] as f64, d_mean[3 * i + 1] as f64, d_mean[3 * i + 2] as f64);
        let dc = view.rotation() * dw;
        let depth = view.to_camera(glam::DVec3::from(gauss.mean)).z;
        let du = dc.x * depth / intr.focal_px[0] * 20.0;
        let dv = dc.y * depth / intr.focal_px[1] * 20.0;
        let expected = (du * du + dv * dv).sqrt();
        assert!(
            (stats[2 * i] as f64 - expected).abs() <= 1e-4 * expected.max(1e-6),
            "Gaussian {i}: statistic {} vs {expected}",
            stats[2 * i]
        );
        assert_eq!(stats[2 * i + 1], 1.0, "visible in the one view");
    }
}
