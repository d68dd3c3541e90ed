//! Pose refinement: a view imaged with a pose off by 2 mm / 1° is brought back through the
//! renderer's gradients — first with the Gaussians held at the truth (the pose alone), then
//! jointly with the whole completion on a synthetic case made with a known perturbation.
#![allow(deprecated)] // burn-ndarray is the CPU backend the tests use.

use burn::lr_scheduler::constant::ConstantLr;
use burn::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;
use burn::module::ParamGroup;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::projector::correction::{corrected_view, random_correction, reprojection_error_px};
use ctadsa_core::data::synth::{PoseErrorSpec, SynthConfig, synthesize};
use ctadsa_core::method::pose::ViewPoses;
use ctadsa_core::method::train::Trainer;
use ctadsa_core::output::export::{RunModels, write_outputs};
use ctadsa_render::{ConeBeamView, Gaussians, RenderSettings, TigreGeometry, ViewSet, render};
use glam::{DQuat, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

mod scratch;
use scratch::scratch;

/// Vessel-like Gaussians: chains of elongated blobs along six random curves in a 50 mm box.
fn vessel_scene(device: &Device) -> (Gaussians, Vec<DVec3>) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut means, mut scales, mut rotations) = (Vec::new(), Vec::new(), Vec::new());
    let mut centres = Vec::new();
    for _ in 0..6 {
        let a = random_correction(22.0, 0.0, &mut rng);
        let b = random_correction(22.0, 0.0, &mut rng);
        let bend = random_correction(8.0, 0.0, &mut rng);
        let (p0, p1, pb) =
            (DVec3::new(a[3], a[4], a[5]), DVec3::new(b[3], b[4], b[5]), DVec3::new(bend[3], bend[4], bend[5]));
        for k in 0..50 {
            let s = k as f64 / 49.0;
            let p = p0.lerp(p1, s) + pb * (4.0 * s * (1.0 - s));
            let dir = (p1 - p0 + pb * (4.0 - 8.0 * s)).normalize();
            let q = DQuat::from_rotation_arc(DVec3::Z, dir);
            means.extend([p.x, p.y, p.z].map(|v| v as f32));
            scales.extend([0.5f32, 0.5, 1.0]);
            rotations.extend([q.w, q.x, q.y, q.z].map(|v| v as f32));
            centres.push(p);
        }
    }
    let n = centres.len();
    let g = Gaussians {
        means: Tensor::from_data(TensorData::new(means, [n, 3]), device),
        scales: Tensor::from_data(TensorData::new(scales, [n, 3]), device),
        rotations: Tensor::from_data(TensorData::new(rotations, [n, 4]), device),
        densities: Tensor::ones([n], device),
    };
    (g, centres)
}

fn view(primary_deg: f64) -> ConeBeamView {
    let g = TigreGeometry { detector_px: [128, 128], pixel_mm: [1.0, 1.0], ..TigreGeometry::reference(primary_deg) };
    ConeBeamView::from_tigre(&g).unwrap()
}

#[test]
fn pose_alone_recovers_a_2mm_1deg_perturbation() {
    let device = Device::ndarray().autodiff();
    let (scene, centres) = vessel_scene(&device);
    let settings = RenderSettings::default();
    let nominal = [view(-90.0), view(0.0)];
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let truth = [random_correction(2.0, 1.0, &mut rng), random_correction(2.0, 1.0, &mut rng)];
    let true_views: Vec<ConeBeamView> =
        nominal.iter().zip(&truth).map(|(v, c)| corrected_view(v, c).unwrap()).collect();
    let targets: Vec<Tensor<3>> =
        true_views.iter().map(|v| render(&scene, &ViewSet::new(vec![*v]).unwrap(), &settings).unwrap()).collect();
    let before: Vec<f64> =
        nominal.iter().zip(&true_views).map(|(a, b)| reprojection_error_px(a, b, &centres).0).collect();

    let mut poses = ViewPoses::new(2, &[], &device);
    let mut optim = AdamConfig::new().with_epsilon(1e-12).init();
    let steps = 250;
    for t in 0..steps {
        let decay = |a: f64, b: f64| a * (b / a).powf(t as f64 / steps as f64);
        let mut loss = Tensor::<1>::zeros([1], &device);
        for (v, target) in targets.iter().enumerate() {
            let seen = poses.apply(&scene, v);
            let image = render(&seen, &ViewSet::new(vec![nominal[v]]).unwrap(), &settings).unwrap();
            loss = loss + (image - target.clone()).powi_scalar(2).mean().reshape([1]);
        }
        let mut grads = loss.backward();
        let g = GradientsParams::from_module(&mut grads, &poses);
        let lr = ModuleLrScheduler::new(ConstantLr::new(decay(2e-3, 5e-5)))
            .with_group(ParamGroup::from_path("translations_mm"), ConstantLr::new(decay(0.1, 2e-3)))
            .step();
        poses = optim.step(lr, poses, g);
    }
    let learned = poses.corrections();
    for v in 0..2 {
        let refined = corrected_view(&nominal[v], &learned[v]).unwrap();
        let (after, worst) = reprojection_error_px(&refined, &true_views[v], &centres);
        eprintln!(
            "view {v}: reprojection error {:.3} px → {after:.3} px (worst {worst:.3}); learned {:?}, true {:?}",
            before[v], learned[v], truth[v]
        );
        assert!(before[v] > 1.0, "the perturbation must be visible (≥ 1 px), got {:.3}", before[v]);
        assert!(after < 0.1 * before[v] && after < 0.15, "view {v}: {after:.3} px left of {:.3} px", before[v]);
    }
}

#[test]
fn joint_refinement_on_a_perturbed_synthetic_case() {
    let dir = scratch("pose-case");
    let cfg = SynthConfig {
        pose_error: Some(PoseErrorSpec { translation_mm: 2.0, rotation_deg: 1.0, seed: 3 }),
        ..SynthConfig::small_procedural("pose-perturbed")
    };
    synthesize(&cfg, &dir, &mut |_| {}).expect("synthesis");
    let case = Case::load(&dir).expect("case loads");
    let text = include_str!(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/quick.toml"));
    let iterations = 200;
    let overrides: Vec<String> = [
        format!("run.iterations={iterations}"),
        "init.n1=1500".into(),
        "init.n2=0".into(),
        "init.n2_mode=none".into(),
        "field.encoding.levels=8".into(),
        "field.encoding.log2_table=12".into(),
        "densify.enabled=false".into(),
        "output.metric_samples=4000".into(),
        "pose.enabled=true".into(),
        "pose.start=20".into(),
    ]
    .into();
    let config = Config::from_toml_str(text, "configs/quick.toml", &overrides).unwrap();
    let mut trainer = Trainer::new(&case, config, Device::ndarray().autodiff()).expect("trainer");
    while trainer.iteration() < iterations {
        trainer.step().expect("step");
    }
    let out = dir.join("run");
    let summary = write_outputs(&out, &case, &RunModels::alone(trainer, &out), &[]).expect("outputs");
    assert!(out.join("poses.json").exists(), "poses.json written");
    let errors = summary.pose_errors.expect("the case knows its true poses");
    for e in &errors {
        eprintln!(
            "view {}: reprojection {:.2} px → {:.2} px; rotation error {:.3}°, translation error {:.2} mm",
            e.view, e.reprojection_before_px, e.reprojection_after_px, e.rotation_error_deg, e.translation_error_mm
        );
    }
    assert_eq!(errors[0].reprojection_before_px, 0.0, "the first view is the exact reference");
    for e in &errors[1..] {
        assert!(e.reprojection_before_px > 1.0, "view {}: perturbation too small to test", e.view);
        assert!(
            e.reprojection_after_px < 0.5 * e.reprojection_before_px,
            "view {}: {:.2} px left of {:.2} px",
            e.view,
            e.reprojection_after_px,
            e.reprojection_before_px
        );
    }
}
