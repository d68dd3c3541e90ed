#![allow(deprecated)] // burn-ndarray is the CPU backend the tests use.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, Optimizer};
use burn::tensor::{Device, Tensor, TensorData};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::FusedAdam;
use crate::method::model::host_vec;

fn random(rng: &mut ChaCha8Rng, n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0f32..1.0) * scale).collect()
}

/// Worst relative difference, with an absolute floor for values near zero.
fn worst_rel(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs() / x.abs().max(y.abs()).max(1e-6)).fold(0.0, f32::max)
}

/// burn's Adam and the fused one on the same gradients for 100 steps (decaying learning rate,
/// gradients spanning six orders of magnitude): parameters and moments agree within 1e-5.
fn compare(weight_decay: Option<f32>, epsilon: f32) {
    let device = Device::ndarray();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let n = 7 * 10_007; // more than one parallel chunk, not a multiple of it
    let init = random(&mut rng, n, 2.0);
    let shape = [n / 7, 7];
    let tensor = |v: Vec<f32>| Tensor::<2>::from_data(TensorData::new(v, shape), &device);
    let reference =
        AdamConfig::new().with_epsilon(epsilon).with_weight_decay(weight_decay.map(WeightDecayConfig::new)).build();
    let fused = FusedAdam::new(epsilon).with_weight_decay(weight_decay);
    let (mut p_ref, mut p_fused) = (tensor(init.clone()), tensor(init));
    let (mut s_ref, mut s_fused) = (None, None);
    for t in 0..100 {
        let scale = 10f32.powi(t % 6 - 4);
        let grad = tensor(random(&mut rng, n, scale));
        let lr = 1e-2 * 0.97f64.powi(t);
        let (p, s) = reference.step(lr, p_ref, grad.clone(), s_ref);
        (p_ref, s_ref) = (p, s);
        let (p, s) = fused.step(lr, p_fused, grad, s_fused);
        (p_fused, s_fused) = (p, s);
    }
    let (a, b) = (s_ref.unwrap().momentum, s_fused.unwrap().momentum);
    assert_eq!(a.time, b.time);
    let d_param = worst_rel(&host_vec(p_ref), &host_vec(p_fused));
    let d_m1 = worst_rel(&host_vec(a.moment_1), &host_vec(b.moment_1));
    let d_m2 = worst_rel(&host_vec(a.moment_2), &host_vec(b.moment_2));
    eprintln!("fused vs burn Adam after 100 steps: {d_param:e} {d_m1:e} {d_m2:e}");
    assert!(d_param <= 1e-5 && d_m1 <= 1e-5 && d_m2 <= 1e-5, "relative differences {d_param} {d_m1} {d_m2}");
}

#[test]
fn fused_adam_follows_burns_adam_for_100_steps() {
    compare(None, 1e-15);
}

#[test]
fn fused_adam_follows_burns_adam_with_coupled_weight_decay() {
    compare(Some(5e-5), 1e-8);
}

#[test]
fn fused_adam_state_is_burns_record() {
    // The state type is burn's AdamState: a checkpoint written with one loads into the other.
    let device = Device::ndarray();
    let p = Tensor::<1>::from_data(TensorData::new(vec![1.0f32, -2.0, 3.0], [3]), &device);
    let g = Tensor::<1>::from_data(TensorData::new(vec![0.5f32, 0.25, -1.0], [3]), &device);
    let (_, state) = FusedAdam::new(1e-8).step(0.1, p.clone(), g.clone(), None);
    let (p_next, _) = AdamConfig::new().with_epsilon(1e-8).build().step(0.1, p.clone(), g.clone(), state.clone());
    let (p_fused, _) = FusedAdam::new(1e-8).step(0.1, p, g, state);
    assert_eq!(host_vec(p_next), host_vec(p_fused));
}
