//! The CPU forward render against a slow independent f64 reference: numerical quadrature of the
//! density along every pixel's ray, with rays built from TIGRE's physical detector description.
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

mod common;

use burn::tensor::Device;
use common::*;
use ctadsa_render::reference::{line_integral_quadrature, pixel_ray_tigre};
use ctadsa_render::{RenderSettings, TigreGeometry, render};

#[test]
fn random_anisotropic_gaussians_match_quadrature() {
    let mut rng = Rng(7);
    let gaussians = random_gaussians(&mut rng, 6, 12.0, (0.4, 4.0));
    let geoms: Vec<TigreGeometry> = [-90.0, 0.0, -45.0, 121.0]
        .iter()
        .map(|&a| TigreGeometry { offset_mm: [1.5, -2.0], ..small_geometry(a, 72, 0.7) })
        .collect();
    let views = view_set(&geoms);
    let t = to_tensors(&gaussians, &Device::ndarray());
    // k = 6: the cut-off tail is below 2e-8 of a ray's peak, so the full-line quadrature applies.
    let img = to_vec(render(&t, &views, &RenderSettings { k_sigma: 6.0, ..Default::default() }).unwrap());
    let (w, h) = (72usize, 72usize);
    for (v, geom) in geoms.iter().enumerate() {
        let mut reference = Vec::with_capacity(w * h);
        for r in 0..h {
            for c in 0..w {
                let (o, d) = pixel_ray_tigre(geom, c as f64, r as f64);
                reference.push(gaussians.iter().map(|g| line_integral_quadrature(g, o, d, 400)).sum::<f64>());
            }
        }
        let ours: Vec<f64> = img[v * w * h..(v + 1) * w * h].iter().map(|&x| x as f64).collect();
        let err = rel_l2(&ours, &reference);
        println!("view {v} (α = {}°): relative L2 error {err:.2e}", geom.primary_deg);
        assert!(err <= 1e-4, "view {v}: relative L2 error {err:e}");
        assert!(reference.iter().filter(|&&x| x > 1e-3).count() > 500, "scene must cover the detector");
    }
}
