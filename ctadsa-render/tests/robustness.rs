//! Edge cases: empty input, one Gaussian, Gaussians crossing the image border, huge and tiny
//! scales, degenerate and non-finite parameters. No panic and no NaN out; bad input reported.
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

mod common;

use burn::tensor::{Device, Tensor, TensorData};
use common::*;
use ctadsa_render::reference::RefGaussian;
use ctadsa_render::{
    ConeBeamView, Gaussians, Intrinsics, MAX_DETECTOR_PX, RenderError, RenderSettings, TigreGeometry, ViewSet,
    VoxelGrid, render, voxelize,
};

fn device() -> Device {
    Device::ndarray().autodiff()
}

fn finite_render_and_grads(g: &Gaussians, views: &ViewSet) -> Vec<f32> {
    let g = Gaussians {
        means: g.means.clone().require_grad(),
        scales: g.scales.clone().require_grad(),
        rotations: g.rotations.clone().require_grad(),
        densities: g.densities.clone().require_grad(),
    };
    let img = render(&g, views, &RenderSettings::default()).unwrap();
    let values = to_vec(img.clone());
    assert!(values.iter().all(|v| v.is_finite()), "non-finite pixel");
    let grads = img.sum().backward();
    for t in [g.means.grad(&grads), g.scales.grad(&grads), g.rotations.grad(&grads)] {
        let t = t.expect("gradient present");
        assert!(to_vec(t).iter().all(|v| v.is_finite()), "non-finite gradient");
    }
    assert!(to_vec(g.densities.grad(&grads).unwrap()).iter().all(|v| v.is_finite()));
    values
}

fn one(mean: [f64; 3], scale: [f64; 3]) -> RefGaussian {
    RefGaussian { mean, scale, quat: [0.9, 0.1, -0.3, 0.2], density: 1.0 }
}

#[test]
fn empty_scene_renders_zeros() {
    let views = view_set(&[small_geometry(-90.0, 16, 1.0), small_geometry(0.0, 16, 1.0)]);
    let g = to_tensors(&[], &device());
    let img = finite_render_and_grads(&g, &views);
    assert_eq!(img.len(), 2 * 16 * 16);
    assert!(img.iter().all(|&v| v == 0.0));
    let vol = voxelize(&g, &VoxelGrid::centred([1.0; 3], [4, 5, 6]).unwrap(), &RenderSettings::default()).unwrap();
    assert_eq!(vol.dims(), [4, 5, 6]);
}

#[test]
fn single_gaussian_and_border_crossing() {
    let views = view_set(&[small_geometry(-90.0, 32, 1.0)]);
    let inside = finite_render_and_grads(&to_tensors(&[one([0.0; 3], [1.5; 3])], &device()), &views);
    assert!(inside.iter().sum::<f32>() > 0.0);
    // Centre just beyond the left image edge: part of the footprint is still visible.
    let edge = 32.0 * 1.0 / 2.0 / 1.4 + 1.0;
    let border = finite_render_and_grads(&to_tensors(&[one([-edge, 0.0, 0.0], [2.0; 3])], &device()), &views);
    let lit: Vec<usize> = border.iter().enumerate().filter(|(_, v)| **v > 0.0).map(|(i, _)| i % 32).collect();
    assert!(!lit.is_empty() && lit.iter().all(|&c| c < 8), "lit columns {lit:?}");
}

#[test]
fn huge_and_tiny_scales_stay_finite() {
    let views = view_set(&[small_geometry(0.0, 24, 1.0)]);
    // Huge: the 3-σ ellipsoid encloses the source; every pixel is evaluated, values finite.
    let huge = finite_render_and_grads(&to_tensors(&[one([0.0; 3], [5e3, 4e3, 6e3])], &device()), &views);
    assert!(huge.iter().all(|&v| v > 0.0));
    // Tiny and absurd scales: no NaN.
    for s in [1e-3, 1e-7, 1e-30, 1e30] {
        finite_render_and_grads(&to_tensors(&[one([0.1, 0.2, 0.3], [s, 1.0, 1.0])], &device()), &views);
    }
}

#[test]
fn degenerate_gaussians_contribute_nothing_and_are_reported() {
    let views = view_set(&[small_geometry(-90.0, 24, 1.0)]);
    let good = one([0.0; 3], [1.0; 3]);
    let cases: Vec<(RefGaussian, &str)> = vec![
        (RefGaussian { mean: [f64::NAN, 0.0, 0.0], ..good }, "mean"),
        (RefGaussian { scale: [1.0, f64::INFINITY, 1.0], ..good }, "scales"),
        (RefGaussian { scale: [1.0, -1.0, 1.0], ..good }, "scales"),
        (RefGaussian { quat: [0.0; 4], ..good }, "quaternion"),
        (RefGaussian { density: f64::NAN, ..good }, "density"),
        (RefGaussian { mean: [0.0, -600.0, 0.0], ..good }, ""), // behind the source: valid but culled
    ];
    let reference = finite_render_and_grads(&to_tensors(&[good], &device()), &views);
    for (bad, word) in cases {
        let t = to_tensors(&[good, bad], &device());
        let img = finite_render_and_grads(&t, &views);
        assert_eq!(img, reference, "a bad Gaussian ({word}) changed the image");
        match t.validate() {
            Err(RenderError::InvalidGaussian { index: 1, problem }) => assert!(problem.contains(word), "{problem}"),
            Ok(()) if word.is_empty() => {}
            other => panic!("expected Gaussian 1 reported for {word}, got {other:?}"),
        }
    }
}

#[test]
fn bad_shapes_views_and_settings_are_errors() {
    let d = device();
    let g = to_tensors(&[one([0.0; 3], [1.0; 3])], &d);
    let views = view_set(&[small_geometry(0.0, 8, 1.0)]);
    let wrong =
        Gaussians { rotations: Tensor::from_data(TensorData::new(vec![1.0f32, 0.0, 0.0], [1, 3]), &d), ..g.clone() };
    assert!(matches!(
        render(&wrong, &views, &RenderSettings::default()),
        Err(RenderError::Shape { name: "rotations", .. })
    ));
    assert!(matches!(
        render(&g, &views, &RenderSettings { k_sigma: f32::NAN, ..Default::default() }),
        Err(RenderError::InvalidSetting(_))
    ));
    assert!(matches!(ViewSet::new(vec![]), Err(RenderError::NoViews)));
    let a = ConeBeamView::from_tigre(&small_geometry(0.0, 8, 1.0)).unwrap();
    let b = ConeBeamView::from_tigre(&small_geometry(0.0, 9, 1.0)).unwrap();
    assert!(matches!(ViewSet::new(vec![a, b]), Err(RenderError::MixedViewSizes { index: 1, .. })));
    let bad_geom = TigreGeometry { dso_mm: 800.0, ..small_geometry(0.0, 8, 1.0) };
    assert!(matches!(ConeBeamView::from_tigre(&bad_geom), Err(RenderError::InvalidView(_))));
    // Angles past a full turn are refused (finite, yet no C-arm pose); a full turn is not.
    for (primary_deg, secondary_deg, ok) in [(1e300, 0.0, false), (0.0, -361.0, false), (-360.0, 360.0, true)] {
        let g = TigreGeometry { primary_deg, secondary_deg, ..small_geometry(0.0, 8, 1.0) };
        let view = ConeBeamView::from_tigre(&g);
        assert_eq!(view.is_ok(), ok, "{primary_deg}°, {secondary_deg}°: {view:?}");
        if let Err(RenderError::InvalidView(m)) = &view {
            assert!(m.contains("±360"), "{m}");
        }
    }
    let not_rigid = glam::DMat4::from_scale(glam::DVec3::splat(2.0));
    let intr = Intrinsics { focal_px: [100.0, 100.0], principal_px: [4.0, 4.0] };
    assert!(ConeBeamView::from_world_to_camera(not_rigid, intr, 8, 8).is_err());
    let rigid = glam::DMat4::from_translation(glam::DVec3::new(0.0, 0.0, 1000.0));
    assert!(ConeBeamView::from_world_to_camera(rigid, intr, MAX_DETECTOR_PX, 8).is_ok());
    let too_wide = ConeBeamView::from_world_to_camera(rigid, intr, MAX_DETECTOR_PX + 1, 8);
    assert!(matches!(&too_wide, Err(RenderError::InvalidView(m)) if m.contains("pixels per side")), "{too_wide:?}");
    assert!(VoxelGrid::centred([0.0, 1.0, 1.0], [2, 2, 2]).is_err());
}

#[test]
fn explicit_world_to_camera_matches_tigre_parameters() {
    let geom = TigreGeometry { offset_mm: [1.0, 2.0], ..small_geometry(33.0, 20, 0.7) };
    let tigre = ConeBeamView::from_tigre(&geom).unwrap();
    let explicit = ConeBeamView::from_world_to_camera(tigre.world_to_camera(), tigre.intrinsics(), 20, 20).unwrap();
    let g = to_tensors(&[one([1.0, 2.0, 3.0], [1.0, 2.0, 0.5])], &Device::ndarray());
    let a = to_vec(render(&g, &ViewSet::new(vec![tigre]).unwrap(), &RenderSettings::default()).unwrap());
    let b = to_vec(render(&g, &ViewSet::new(vec![explicit]).unwrap(), &RenderSettings::default()).unwrap());
    assert_eq!(a, b);
}

#[test]
fn voxelize_matches_direct_evaluation() {
    let mut rng = Rng(5);
    let gs = random_gaussians(&mut rng, 5, 4.0, (0.5, 2.0));
    let grid = VoxelGrid::from_bounds([-8.0, -7.0, -6.0], [8.0, 9.0, 6.0], [16, 20, 12]).unwrap();
    let vol = to_vec(
        voxelize(&to_tensors(&gs, &Device::ndarray()), &grid, &RenderSettings { k_sigma: 8.0, ..Default::default() })
            .unwrap(),
    );
    let mut worst = 0.0f64;
    let qs: Vec<_> = gs.iter().map(|g| g.precision()).collect();
    for x in 0..16u32 {
        for y in 0..20u32 {
            for z in 0..12u32 {
                let c = grid.voxel_centre_mm([x, y, z]);
                let p = glam::DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64);
                let expect: f64 = gs.iter().zip(&qs).map(|(g, q)| g.density_at(p, q)).sum();
                let got = vol[((x * 20 + y) * 12 + z) as usize] as f64;
                worst = worst.max((got - expect).abs());
            }
        }
    }
    assert!(worst < 1e-5, "worst absolute error {worst}");
}

/// The Gaussians as the CPU kernels' flat host arrays `(means, scales, rotations, densities)`.
fn host_arrays(gs: &[RefGaussian]) -> [Vec<f32>; 4] {
    let flat = |f: &dyn Fn(&RefGaussian) -> Vec<f64>| -> Vec<f32> { gs.iter().flat_map(f).map(|v| v as f32).collect() };
    [flat(&|g| g.mean.to_vec()), flat(&|g| g.scale.to_vec()), flat(&|g| g.quat.to_vec()), flat(&|g| vec![g.density])]
}

/// The CPU forward gives the same image, bit for bit, on 1, 2 or 3 threads (it bins and adds
/// Gaussians in index order), and a small scene rendered right after a larger one on the same
/// thread (the forward keeps its buffers between calls) equals the small scene rendered first.
#[test]
fn cpu_forward_is_deterministic_across_threads_and_calls() {
    use ctadsa_render::cpu::{self, HostGaussians};
    let mut rng = Rng(42);
    // More than two chunks of the forward's parallel projection (2048 Gaussians each).
    let big = random_gaussians(&mut rng, 5000, 40.0, (0.3, 3.0));
    let small = &big[..700];
    let views = view_set(&[small_geometry(0.0, 96, 1.0), small_geometry(90.0, 96, 1.0)]);
    let render_on = |gs: &[RefGaussian]| {
        let [m, s, r, d] = host_arrays(gs);
        cpu::render(&HostGaussians { means: &m, scales: &s, rotations: &r, densities: &d }, views.packed(), 3.0)
    };
    let pool = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
    let reference = pool(1).install(|| render_on(&big));
    assert!(reference.iter().filter(|v| **v > 0.0).count() > 1000, "the scene covers the views");
    for threads in [2, 3] {
        let image = pool(threads).install(|| render_on(&big));
        assert!(image == reference, "{threads} threads differ from 1");
    }
    let small_first = pool(1).install(|| render_on(small));
    let small_after_big = pool(1).install(|| {
        render_on(&big);
        render_on(small)
    });
    assert!(small_after_big == small_first, "reused buffers changed the result");
    assert!(small_first != reference);
}
