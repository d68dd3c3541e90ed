#![allow(deprecated)] // burn-ndarray is the CPU backend the tests use.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::{AdamConfig, Optimizer};
use burn::tensor::{Device, Tensor, TensorData};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::{FusedAdam, FusedAdamState};
use crate::readback::host_vec;

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
    let (a, b) = (s_ref.unwrap().momentum, s_fused.unwrap());
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

/// The fused state's record is burn's `AdamState`'s leaf for leaf (names, shapes, bits), and
/// each type rebuilds from the other's record: a checkpoint written with one loads into the other.
#[test]
fn fused_adam_state_is_burns_record() {
    use burn::optim::{RecordState, StateSink, StateSource};
    let device = Device::ndarray();
    let p = Tensor::<2>::from_data(TensorData::new(vec![1.0f32, -2.0, 3.0, 0.5, -0.25, 8.0], [2, 3]), &device);
    let g = Tensor::<2>::from_data(TensorData::new(vec![0.5f32, 0.25, -1.0, 1e-3, -3.0, 0.0], [2, 3]), &device);
    let burns = AdamConfig::new().with_epsilon(1e-8).build();
    let (p1, burn_state) = burns.step(0.1, p.clone(), g.clone(), None);
    let (_, burn_state) = burns.step(0.1, p1, g.clone(), burn_state);
    let (q1, fused_state) = FusedAdam::new(1e-8).step(0.1, p.clone(), g.clone(), None);
    let (_, fused_state) = FusedAdam::new(1e-8).step(0.1, q1, g.clone(), fused_state);
    let (burn_state, fused_state) = (burn_state.unwrap(), fused_state.unwrap());
    let sink = |flatten: &dyn Fn(&mut StateSink)| {
        let mut out = StateSink::default();
        flatten(&mut out);
        out
    };
    let (a, b) = (sink(&|o| burn_state.state_flatten("7", o)), sink(&|o| fused_state.state_flatten("7", o)));
    assert_eq!(a.scalars, b.scalars);
    let leaves =
        |s: &StateSink| s.tensors.iter().map(|(name, d)| (name.clone(), d.shape().to_vec())).collect::<Vec<_>>();
    assert_eq!(leaves(&a), leaves(&b));
    for ((name, x), (_, y)) in a.tensors.iter().zip(&b.tensors) {
        let (x, y) = (x.to_vec::<f32>().unwrap(), y.to_vec::<f32>().unwrap());
        assert!(x.iter().zip(&y).all(|(u, v)| u.to_bits() == v.to_bits()), "{name}: {x:?} vs {y:?}");
    }
    let source = |s: StateSink| {
        let mut src = StateSource::new(s.scalars.into_iter().collect());
        for (name, data) in s.tensors {
            src.insert_tensor(name, data);
        }
        src
    };
    let from_fused = burn::optim::AdamState::<2>::state_unflatten("7", &mut source(b), &device).unwrap();
    let from_burn = FusedAdamState::<2>::state_unflatten("7", &mut source(a), &device).unwrap();
    assert_eq!((from_fused.momentum.time, from_burn.time), (2, 2));
    assert_eq!(host_vec(from_fused.momentum.moment_2), host_vec(fused_state.moment_2));
    assert_eq!(host_vec(from_burn.moment_1), host_vec(burn_state.momentum.moment_1));
}

/// Terms below the smallest normal f32 are flushed to zero (no subnormal arithmetic): the update
/// stays within 1e-37 of the f64 formula, and normal-range values are untouched.
#[test]
fn subnormal_terms_are_flushed_and_the_update_stays_exact_to_1e_37() {
    use super::kernel::{AdamCoefficients, adam_in_place};
    let c =
        AdamCoefficients { beta_1: 0.9, beta_2: 0.999, epsilon: 1e-15, weight_decay: Some(5e-5), lr: 1e-3, time: 500 };
    // Gradients whose square underflows, moments in or near the subnormal range, tiny parameters.
    let mut p = vec![1e-3f32, 1e-36, -2e-3, 0.5];
    let g = vec![1e-20f32, 3e-39, -1e-19, 0.25];
    let mut m = vec![1e-38f32, 5e-39, -2e-38, 0.01];
    let mut v = vec![1e-39f32, 1e-38, 2e-39, 1e-4];
    let (p0, m0, v0) = (p.clone(), m.clone(), v.clone());
    adam_in_place(&mut p, &g, &mut m, &mut v, c);
    let (bc2_sqrt, combined) = c.bias_corrections();
    for k in 0..p.len() {
        let gk = p0[k] as f64 * 5e-5 + g[k] as f64;
        let mk = m0[k] as f64 * 0.9 + gk * 0.1;
        let vk = v0[k] as f64 * 0.999 + gk * gk * (1.0 - 0.999f32) as f64;
        let pk = p0[k] as f64 - mk * combined as f64 / (vk.sqrt() + 1e-15 * bc2_sqrt as f64) * 1e-3;
        assert!((m[k] as f64 - mk).abs() <= 1e-37 + 1e-6 * mk.abs(), "m[{k}] {} vs {mk}", m[k]);
        assert!((v[k] as f64 - vk).abs() <= 1e-37 + 1e-6 * vk.abs(), "v[{k}] {} vs {vk}", v[k]);
        assert!(m[k] == 0.0 || m[k].is_normal(), "m[{k}] = {} is subnormal", m[k]);
        assert!(v[k] == 0.0 || v[k].is_normal(), "v[{k}] = {} is subnormal", v[k]);
        // The parameter step divides by √v + ε, so a flushed v moves it by up to lr·m/ε-scale terms:
        // compare where v is normal-range.
        if v0[k] > 1e-30 {
            assert!((p[k] as f64 - pk).abs() <= 1e-6 * pk.abs().max(1e-6), "p[{k}] {} vs {pk}", p[k]);
        }
    }
}
