//! Analytic checks of the forward render (CPU backend): central-ray values, detector mass,
//! point-phantom geometry, and exact zeros away from the footprints.
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

mod common;

use burn::tensor::Device;
use common::*;
use ctadsa_render::reference::{RefGaussian, project_point_tigre};
use ctadsa_render::{ConeBeamView, RenderSettings, TigreGeometry, ViewSet, render};
use glam::DVec3;

fn device() -> Device {
    Device::ndarray()
}

fn render_one(g: &[RefGaussian], views: &ViewSet, k: f32) -> Vec<f32> {
    let t = to_tensors(g, &device());
    to_vec(render(&t, views, &RenderSettings { k_sigma: k, ..Default::default() }).unwrap())
}

#[test]
fn isotropic_central_ray_is_rho_sigma_sqrt_2pi_for_any_view() {
    let (rho, sigma) = (0.7, 2.0);
    let g = RefGaussian { mean: [0.0; 3], scale: [sigma; 3], quat: [0.3, -0.2, 0.9, 0.1], density: rho };
    let expected = rho * sigma * (2.0 * std::f64::consts::PI).sqrt();
    for (primary, secondary) in [(-90.0, 0.0), (0.0, 0.0), (37.0, 0.0), (135.0, 20.0), (-45.0, -15.0)] {
        let geom = TigreGeometry { secondary_deg: secondary, ..small_geometry(primary, 33, 0.5) };
        let img = render_one(&[g], &view_set(&[geom]), 3.0);
        let centre = img[16 * 33 + 16] as f64;
        assert!(
            ((centre - expected) / expected).abs() < 1e-5,
            "angle ({primary}, {secondary}): centre {centre} vs {expected}"
        );
    }
}

#[test]
fn isotropic_gaussian_anywhere_on_a_pixel_ray_gives_the_same_value() {
    let geom = small_geometry(25.0, 41, 0.8);
    let view = ConeBeamView::from_tigre(&geom).unwrap();
    let (col, row) = (7u32, 30u32);
    let dir = view.pixel_ray(col as f64, row as f64);
    for depth in [420.0, 500.0, 590.0] {
        let p = view.source_mm() + depth * dir;
        let g = RefGaussian { mean: p.to_array(), scale: [1.3; 3], quat: [1.0, 0.0, 0.0, 0.0], density: 1.0 };
        let img = render_one(&[g], &view_set(&[geom]), 3.0);
        let v = img[(row * 41 + col) as usize] as f64;
        let expected = 1.3 * (2.0 * std::f64::consts::PI).sqrt();
        assert!(((v - expected) / expected).abs() < 2e-5, "depth {depth}: {v} vs {expected}");
    }
}

#[test]
fn detector_integral_is_mass_times_magnification_squared() {
    let g = RefGaussian { mean: [0.0; 3], scale: [3.0, 2.0, 4.0], quat: [0.8, 0.3, -0.4, 0.2], density: 0.9 };
    for primary in [-90.0, 0.0, 60.0] {
        let geom = small_geometry(primary, 161, 0.5);
        let img = render_one(&[g], &view_set(&[geom]), 5.0);
        let total: f64 = img.iter().map(|&v| v as f64).sum::<f64>() * 0.25;
        let m = geom.dsd_mm / geom.dso_mm;
        let expected = g.mass() * m * m;
        let rel = (total - expected) / expected;
        assert!(rel.abs() < 5e-3, "angle {primary}: Σ p·px² = {total}, mass·M² = {expected} ({rel:+e})");
    }
}

/// Brightest pixel and intensity-weighted centroid of a rendered point-like Gaussian.
fn peak_and_centroid(img: &[f32], w: usize) -> ((usize, usize), (f64, f64)) {
    let (mut best, mut at) = (f32::MIN, 0);
    let (mut sw, mut sc, mut sr) = (0.0, 0.0, 0.0);
    for (i, &v) in img.iter().enumerate() {
        if v > best {
            best = v;
            at = i;
        }
        let (c, r) = ((i % w) as f64, (i / w) as f64);
        sw += v as f64;
        sc += v as f64 * c;
        sr += v as f64 * r;
    }
    ((at % w, at / w), (sc / sw, sr / sw))
}

#[test]
fn point_phantom_lands_where_the_conventions_say() {
    let points = [DVec3::new(10.0, -12.0, 9.0), DVec3::new(-14.0, 9.0, -8.0), DVec3::new(3.3, 4.4, 5.5)];
    let geoms = [
        small_geometry(-90.0, 128, 0.5),
        small_geometry(0.0, 128, 0.5),
        TigreGeometry { offset_mm: [3.2, -1.7], ..small_geometry(-90.0, 128, 0.5) },
        TigreGeometry {
            offset_mm: [-4.1, 2.6],
            detector_px: [120, 100],
            pixel_mm: [0.6, 0.4],
            ..small_geometry(0.0, 128, 0.5)
        },
    ];
    for geom in geoms {
        for p in points {
            let (col, row) = project_point_tigre(&geom, p);
            let w = geom.detector_px[0] as usize;
            let h = geom.detector_px[1] as f64;
            assert!(col > 5.0 && col < w as f64 - 5.0 && row > 5.0 && row < h - 5.0, "test point {p} off the detector");
            // A sharp point: brightest pixel.
            let sharp = RefGaussian { mean: p.to_array(), scale: [0.1; 3], quat: [1.0, 0.0, 0.0, 0.0], density: 1.0 };
            let img = render_one(&[sharp], &view_set(&[geom]), 3.0);
            let (peak, _) = peak_and_centroid(&img, w);
            assert_eq!(
                peak,
                (col.round() as usize, row.round() as usize),
                "{geom:?} point {p}: predicted ({col:.2}, {row:.2})"
            );
            // A blob: centroid to sub-pixel accuracy.
            let blob = RefGaussian { scale: [0.6; 3], ..sharp };
            let img = render_one(&[blob], &view_set(&[geom]), 5.0);
            let (_, (cc, cr)) = peak_and_centroid(&img, w);
            assert!(
                (cc - col).abs() < 0.02 && (cr - row).abs() < 0.02,
                "{geom:?} point {p}: centroid ({cc:.3}, {cr:.3}) vs ({col:.3}, {row:.3})"
            );
        }
    }
}

#[test]
fn ap_and_lat_orientation() {
    // AP (−90°): source at −y, +x to the right (larger column), +z up (smaller row).
    let ap = ConeBeamView::from_tigre(&small_geometry(-90.0, 65, 0.5)).unwrap();
    assert!((ap.source_mm() - DVec3::new(0.0, -500.0, 0.0)).length() < 1e-9);
    let c = ap.project(DVec3::ZERO).unwrap();
    assert!(ap.project(DVec3::new(10.0, 0.0, 0.0)).unwrap().x > c.x + 10.0);
    assert!(ap.project(DVec3::new(0.0, 0.0, 10.0)).unwrap().y < c.y - 10.0);
    // LAT (0°): source at +x, +y to the right.
    let lat = ConeBeamView::from_tigre(&small_geometry(0.0, 65, 0.5)).unwrap();
    assert!((lat.source_mm() - DVec3::new(500.0, 0.0, 0.0)).length() < 1e-9);
    let c = lat.project(DVec3::ZERO).unwrap();
    assert!(lat.project(DVec3::new(0.0, 10.0, 0.0)).unwrap().x > c.x + 10.0);
    // Secondary angle tilts the source out of z = 0 (reference world2cam: source z = −DSO sin β).
    let tilted =
        ConeBeamView::from_tigre(&TigreGeometry { secondary_deg: 30.0, ..small_geometry(-90.0, 65, 0.5) }).unwrap();
    let s = tilted.source_mm();
    assert!((s - DVec3::new(0.0, -500.0 * 30f64.to_radians().cos(), -250.0)).length() < 1e-9, "{s}");
    let iso = tilted.project(DVec3::ZERO).unwrap();
    assert!((iso.x - 32.0).abs() < 1e-9 && (iso.y - 32.0).abs() < 1e-9);
}

#[test]
fn rays_that_miss_are_exactly_zero() {
    let geom = small_geometry(-90.0, 96, 0.5);
    let g = RefGaussian { mean: [-12.0, 0.0, 8.0], scale: [0.8, 0.5, 1.1], quat: [0.9, 0.1, 0.2, 0.3], density: 1.0 };
    let img = render_one(&[g], &view_set(&[geom]), 3.0);
    let (col, row) = project_point_tigre(&geom, DVec3::from(g.mean));
    let mut nonzero = 0;
    for (i, &v) in img.iter().enumerate() {
        let (c, r) = ((i % 96) as f64, (i / 96) as f64);
        let far = ((c - col).powi(2) + (r - row).powi(2)).sqrt() > 12.0;
        if far {
            assert_eq!(v, 0.0, "pixel ({c}, {r}) far from the footprint is {v}");
        } else if v > 0.0 {
            nonzero += 1;
        }
    }
    assert!(nonzero > 10);
    // Entirely off the detector: a blank image.
    let off = RefGaussian { mean: [200.0, 0.0, 0.0], ..g };
    assert!(render_one(&[off], &view_set(&[geom]), 3.0).iter().all(|&v| v == 0.0));
}

#[test]
fn footprint_cutoff_is_the_exact_k_sigma_ellipsoid() {
    use ctadsa_render::reference::{pixel_ray_tigre, ray_mahalanobis2};
    let geom = small_geometry(30.0, 64, 0.5);
    let g = RefGaussian { mean: [2.0, -3.0, 1.0], scale: [2.5, 0.7, 1.2], quat: [0.5, -0.4, 0.7, 0.2], density: 1.0 };
    let k = 2.5f64;
    let img = render_one(&[g], &view_set(&[geom]), k as f32);
    let mut inside = 0;
    for (i, &v) in img.iter().enumerate() {
        let (c, r) = ((i % 64) as f64, (i / 64) as f64);
        let (o, d) = pixel_ray_tigre(&geom, c, r);
        let m2 = ray_mahalanobis2(&g, o, d);
        // Away from the boundary (rounding), the pixel is lit iff its ray meets the ellipsoid.
        if m2 < k * k * 0.999 {
            assert!(v > 0.0, "pixel ({c}, {r}) inside (c = {m2}) is dark");
            inside += 1;
        } else if m2 > k * k * 1.001 {
            assert_eq!(v, 0.0, "pixel ({c}, {r}) outside (c = {m2}) is lit");
        }
    }
    assert!(inside > 50);
}
