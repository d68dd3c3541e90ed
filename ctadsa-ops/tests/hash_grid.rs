//! The hash encoding: the backend op against a direct per-point evaluation, its gradients
//! against autodiff through the same encoding written with plain tensor operations, and the
//! wgpu kernels against the CPU ones (when a wgpu adapter exists).
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

use burn::tensor::{Device, Distribution, Tensor, TensorData};
use ctadsa_ops::hash_grid::{HashGrid, HashGridConfig, encode_reference};
use ctadsa_ops::readback::host_vec;

fn config() -> HashGridConfig {
    // Small table so that both dense and hashed levels occur.
    HashGridConfig { levels: 6, features: 2, log2_table: 10, base_resolution: 4.0, growth: 1.8, ..Default::default() }
}

fn points(n: usize, device: &Device) -> Tensor<2> {
    let mut s = 99u64;
    let v: Vec<f32> = (0..3 * n)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            // Mostly inside [0, 1], a few outside to exercise the clamp.
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 1.1 - 0.05
        })
        .collect();
    Tensor::from_data(TensorData::new(v, [n, 3]), device)
}

fn grid(device: &Device) -> HashGrid {
    let mut g = HashGrid::new(config(), 11, device);
    // Larger values than the ±1e-4 initialisation so that errors would show.
    let [f, r] = g.tables.val().dims();
    g.tables = burn::module::Param::from_tensor(Tensor::random([f, r], Distribution::Uniform(-1.0, 1.0), device));
    g
}

#[test]
fn op_matches_direct_evaluation() {
    let device = Device::ndarray();
    let c = config();
    assert!((0..c.levels).any(|l| c.dense(l)) && (0..c.levels).any(|l| !c.dense(l)));
    let g = grid(&device);
    let u = points(200, &device);
    let ours = host_vec(g.forward(u.clone()));
    let tables = host_vec(g.tables.val());
    let pts = host_vec(u);
    for i in 0..200 {
        let p = [pts[3 * i] as f64, pts[3 * i + 1] as f64, pts[3 * i + 2] as f64];
        let r = encode_reference(&c, &tables, p);
        for (k, v) in r.iter().enumerate() {
            let o = ours[i * c.output_dim() + k] as f64;
            assert!((o - v).abs() < 1e-5, "point {i} feature {k}: {o} vs {v}");
        }
    }
}

#[test]
fn op_gradients_match_tensor_op_autodiff() {
    let device = Device::ndarray().autodiff();
    let g = grid(&device);
    let u = points(150, &device).require_grad();
    let w = Tensor::<2>::random([150, config().output_dim()], Distribution::Uniform(-1.0, 1.0), &device);
    let a = (g.forward(u.clone()) * w.clone()).sum().backward();
    let b = (g.forward_tensor_ops(u.clone()) * w).sum().backward();
    for (name, x, y) in [
        ("positions", u.grad(&a).unwrap(), u.grad(&b).unwrap()),
        ("tables", g.tables.val().grad(&a).unwrap(), g.tables.val().grad(&b).unwrap()),
    ] {
        let (x, y) = (host_vec(x), host_vec(y));
        let worst = x.iter().zip(&y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
        let scale = y.iter().map(|q| q.abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1e-4 * scale.max(1.0), "{name}: worst difference {worst} (scale {scale})");
    }
}

/// The table gradient's buffer is pooled between backward passes (ndarray): a gradient the
/// caller still holds is never written by a later pass, and a reused buffer starts from zero.
#[test]
fn pooled_table_gradient_is_zeroed_and_never_overwrites_a_held_one() {
    let device = Device::ndarray().autodiff();
    let g = grid(&device);
    let u = points(150, &device);
    let w = Tensor::<2>::random([150, config().output_dim()], Distribution::Uniform(-1.0, 1.0), &device);
    let table_grad = |w: &Tensor<2>| {
        let grads = (g.forward(u.clone()) * w.clone()).sum().backward();
        g.tables.val().grad(&grads).expect("the tables get a gradient")
    };
    let first = table_grad(&w);
    let expected = host_vec(first.clone());
    assert!(expected.iter().any(|v| *v != 0.0));
    // A different upstream gradient while `first` is alive: a fresh buffer, `first` untouched.
    let other = table_grad(&(w.clone() * 3.0));
    assert_eq!(host_vec(first.clone()), expected);
    assert_ne!(host_vec(other.clone()), expected);
    drop((first, other));
    // Nobody holds the pooled buffer now: it is reused, and must have been cleared.
    for _ in 0..2 {
        assert_eq!(host_vec(table_grad(&w)), expected);
    }
}

#[cfg(feature = "wgpu")]
#[test]
fn wgpu_kernels_match_cpu() {
    let adapter = ctadsa_render::wgpu_adapter();
    let Ok(name) = adapter else {
        if std::env::var("CTADSA_REQUIRE_WGPU").is_ok_and(|v| v == "1") {
            panic!("CTADSA_REQUIRE_WGPU=1 but {}", adapter.unwrap_err());
        }
        eprintln!("SKIPPED: hash-grid wgpu parity not run: {}", adapter.unwrap_err());
        return;
    };
    eprintln!("wgpu adapter: {name}");
    use ctadsa_render::F32Add;
    // One set of tables for both runs (random tables differ per call).
    let table_data = grid(&Device::ndarray()).tables.val().into_data();
    let run = |device: Device, f32_add: F32Add| {
        let device = device.autodiff();
        let tables = Tensor::<2>::from_data(table_data.clone(), &device).require_grad();
        let g = HashGrid {
            tables: burn::module::Param::from_tensor(tables),
            config: HashGridConfig { f32_add, ..config() },
        };
        let u = Tensor::<2>::from_data(points(300, &Device::ndarray()).into_data(), &device).require_grad();
        let w = Tensor::<2>::from_data(
            TensorData::new(
                (0..300 * config().output_dim()).map(|i| ((i * 7919) % 13) as f32 / 13.0 - 0.5).collect::<Vec<_>>(),
                [300, config().output_dim()],
            ),
            &device,
        );
        let out = g.forward(u.clone());
        let grads = (out.clone() * w).sum().backward();
        (host_vec(out), host_vec(u.grad(&grads).unwrap()), host_vec(g.tables.val().grad(&grads).unwrap()))
    };
    let a = run(Device::ndarray(), F32Add::Auto);
    // The table gradient is added atomically: with the device's f32 add and with the loop.
    for mode in [F32Add::CompareExchange, F32Add::Auto] {
        let b = run(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice), mode);
        for (name, x, y) in [("forward", &a.0, &b.0), ("positions", &a.1, &b.1), ("tables", &a.2, &b.2)] {
            let worst = x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            let scale = x.iter().map(|q| q.abs()).fold(0.0f32, f32::max).max(1.0);
            assert!(worst <= 1e-4 * scale, "{name} ({mode:?}): wgpu differs by {worst} (scale {scale})");
        }
    }
}
