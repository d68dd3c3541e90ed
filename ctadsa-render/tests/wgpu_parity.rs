//! The wgpu (CubeCL) kernels against the CPU kernels: forward, all gradients, the densification
//! statistic and voxelisation agree within 1e-4 relative, with the device's f32 atomic add and
//! with the compare-and-swap loop, and with a footprint's rows split among 1, 4 and 64 units;
//! edge cases stay finite.
//!
//! Needs a wgpu adapter (a GPU or Mesa lavapipe). Without one every test prints why and returns;
//! with `CTADSA_REQUIRE_WGPU=1` (CI) a missing adapter is a failure.
#![cfg(feature = "wgpu")]
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

mod common;

use burn::tensor::{Device, DeviceKind, Tensor, TensorData};
use common::*;
use ctadsa_render::reference::RefGaussian;
use ctadsa_render::{F32Add, Gaussians, RenderSettings, ViewSet, VoxelGrid, render_with_stats, voxelize};

/// The wgpu device, or `None` (after printing why) when there is no adapter.
fn gpu() -> Option<Device> {
    match ctadsa_render::wgpu_adapter() {
        Ok(name) => {
            eprintln!("wgpu adapter: {name}");
            Some(Device::wgpu(DeviceKind::DefaultDevice))
        }
        Err(why) => {
            if std::env::var("CTADSA_REQUIRE_WGPU").is_ok_and(|v| v == "1") {
                panic!("CTADSA_REQUIRE_WGPU=1 but {why}");
            }
            eprintln!("SKIPPED: wgpu parity test not run: {why}");
            None
        }
    }
}

/// Runs `check` with the settings of each way of adding f32 atomically (`Auto` adds natively
/// where the device can: the adapter line printed says whether it does).
fn for_each_f32_add(check: impl Fn(&RenderSettings)) {
    for f32_add in [F32Add::CompareExchange, F32Add::Auto] {
        println!("{f32_add:?}");
        check(&RenderSettings { f32_add, ..Default::default() });
    }
}

struct Outputs {
    image: Vec<f64>,
    grads: [Vec<f64>; 5],
}

fn run(gs: &[RefGaussian], views: &ViewSet, device: &Device, weights: &[f32], settings: &RenderSettings) -> Outputs {
    let device = device.clone().autodiff();
    let t = to_tensors(gs, &device);
    let g = Gaussians {
        means: t.means.require_grad(),
        scales: t.scales.require_grad(),
        rotations: t.rotations.require_grad(),
        densities: t.densities.require_grad(),
    };
    let probe = Tensor::<2>::zeros([gs.len(), 2], &device).require_grad();
    let img = render_with_stats(&g, probe.clone(), views, settings).unwrap();
    let dims = img.dims();
    let w = Tensor::<3>::from_data(TensorData::new(weights.to_vec(), dims), &device);
    let grads = (img.clone() * w).sum().backward();
    let f = |v: Vec<f32>| v.into_iter().map(|x| x as f64).collect::<Vec<_>>();
    Outputs {
        image: f(to_vec(img)),
        grads: [
            f(to_vec(g.means.grad(&grads).unwrap())),
            f(to_vec(g.scales.grad(&grads).unwrap())),
            f(to_vec(g.rotations.grad(&grads).unwrap())),
            f(to_vec(g.densities.grad(&grads).unwrap())),
            f(to_vec(probe.grad(&grads).unwrap())),
        ],
    }
}

#[test]
fn forward_and_gradients_match_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let mut rng = Rng(2024);
    let gs = random_gaussians(&mut rng, 60, 15.0, (0.3, 3.0));
    let views =
        view_set(&[small_geometry(-90.0, 64, 0.8), small_geometry(0.0, 64, 0.8), small_geometry(-45.0, 64, 0.8)]);
    let weights: Vec<f32> = (0..3 * 64 * 64).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let cpu = run(&gs, &views, &Device::ndarray(), &weights, &RenderSettings::default());
    // Each way of adding, and the render kernels with 1, 4 and 64 units per Gaussian (a
    // footprint's rows split among them; 64: the whole workgroup).
    for_each_f32_add(|settings| {
        for row_split in [1, 4, 64] {
            let settings = &RenderSettings { row_split, ..*settings };
            let mode = (settings.f32_add, row_split);
            let wgpu = run(&gs, &views, &gpu, &weights, settings);
            let err = rel_l2(&wgpu.image, &cpu.image);
            println!("image: relative L2 {err:.2e}");
            assert!(err <= 1e-4, "forward ({mode:?}) differs: {err:e}");
            for (name, (a, b)) in ["means", "scales", "rotations", "densities", "screen stats"]
                .iter()
                .zip(wgpu.grads.iter().zip(cpu.grads.iter()))
            {
                let err = rel_l2(a, b);
                println!("{name}: relative L2 {err:.2e}");
                assert!(err <= 1e-4, "{name} ({mode:?}) differ: {err:e}");
            }
        }
    });
}

#[test]
fn voxelize_matches_the_cpu() {
    let Some(gpu) = gpu() else { return };
    let mut rng = Rng(77);
    let gs = random_gaussians(&mut rng, 40, 6.0, (0.5, 2.0));
    let grid = VoxelGrid::from_bounds([-9.0, -8.0, -7.0], [9.0, 8.0, 7.0], [24, 20, 18]).unwrap();
    let s = RenderSettings::default();
    let b: Vec<f64> =
        to_vec(voxelize(&to_tensors(&gs, &Device::ndarray()), &grid, &s).unwrap()).into_iter().map(f64::from).collect();
    for_each_f32_add(|settings| {
        let a: Vec<f64> =
            to_vec(voxelize(&to_tensors(&gs, &gpu), &grid, settings).unwrap()).into_iter().map(f64::from).collect();
        let err = rel_l2(&a, &b);
        println!("volume: relative L2 {err:.2e}");
        assert!(err <= 1e-5, "{:?}: {err:e}", settings.f32_add);
    });
}

#[test]
fn edge_cases_stay_finite_on_the_gpu() {
    let Some(gpu) = gpu() else { return };
    let views = view_set(&[small_geometry(0.0, 24, 1.0)]);
    let good = RefGaussian { mean: [0.0; 3], scale: [1.0; 3], quat: [1.0, 0.0, 0.0, 0.0], density: 1.0 };
    let weights = vec![1.0f32; 24 * 24];
    let reference = run(&[good], &views, &gpu, &weights, &RenderSettings::default());
    let cases = [
        RefGaussian { mean: [f64::NAN, 0.0, 0.0], ..good },
        RefGaussian { scale: [1.0, -1.0, 1.0], ..good },
        RefGaussian { quat: [0.0; 4], ..good },
        RefGaussian { density: f64::INFINITY, ..good },
    ];
    for bad in cases {
        let out = run(&[good, bad], &views, &gpu, &weights, &RenderSettings::default());
        assert!(out.image.iter().all(|v| v.is_finite()));
        assert!(rel_l2(&out.image, &reference.image) < 1e-6, "bad Gaussian {bad:?} changed the image");
        for g in &out.grads {
            assert!(g.iter().all(|v| v.is_finite()), "non-finite gradient for {bad:?}");
        }
    }
    let huge = run(&[RefGaussian { scale: [5e3; 3], ..good }], &views, &gpu, &weights, &RenderSettings::default());
    assert!(huge.image.iter().all(|v| v.is_finite() && *v > 0.0));
    let empty = run(&[], &views, &gpu, &weights, &RenderSettings::default());
    assert!(empty.image.iter().all(|&v| v == 0.0));
}
