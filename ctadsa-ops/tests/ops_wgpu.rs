//! The field's MLP layer op, the bounded scale op, the SSIM window-blur op, the SSIM op, the anchoring term and the loss terms on wgpu against the CPU (when a wgpu
//! adapter exists; `CTADSA_REQUIRE_WGPU=1` makes a missing adapter a failure).
#![cfg(feature = "wgpu")]
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_ops::blur_op::window_blur;
use ctadsa_ops::linear_op::{Activation, fused_linear};
use ctadsa_ops::readback::host_vec;
use ctadsa_ops::scale_op::bounded_scale;
use ctadsa_ops::ssim_op::ssim_mean;

fn values(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed;
    (0..len)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        })
        .collect()
}

fn wgpu_or_skip(what: &str) -> Option<Device> {
    match ctadsa_render::wgpu_adapter() {
        Ok(name) => {
            eprintln!("wgpu adapter: {name}");
            Some(Device::wgpu(burn::tensor::DeviceKind::DefaultDevice))
        }
        Err(e) if std::env::var("CTADSA_REQUIRE_WGPU").is_ok_and(|v| v == "1") => {
            panic!("CTADSA_REQUIRE_WGPU=1 but {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: {what} wgpu parity not run: {e}");
            None
        }
    }
}

fn assert_close(name: &str, a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len(), "{name}");
    let worst = a.iter().zip(b).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    let scale = a.iter().map(|q| q.abs()).fold(0.0f32, f32::max).max(1.0);
    assert!(worst <= 1e-4 * scale, "{name}: wgpu differs by {worst} (scale {scale})");
}

#[test]
fn window_blur_on_wgpu_matches_cpu() {
    let Some(gpu) = wgpu_or_skip("window blur") else { return };
    let [v, h, w] = [2, 19, 27];
    let (x, up) = (values(v * h * w, 1), values(v * h * w, 2));
    let run = |device: Device| {
        let device = device.autodiff();
        let x = Tensor::<3>::from_data(TensorData::new(x.clone(), [v, h, w]), &device).require_grad();
        let up = Tensor::<3>::from_data(TensorData::new(up.clone(), [v, h, w]), &device);
        let out = window_blur(x.clone());
        let grads = (out.clone() * up).sum().backward();
        (host_vec(out), host_vec(x.grad(&grads).unwrap()))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert_close("blur forward", &a.0, &b.0);
    assert_close("blur backward", &a.1, &b.1);
}

#[test]
fn bounded_scale_on_wgpu_matches_cpu() {
    let Some(gpu) = wgpu_or_skip("bounded scale") else { return };
    let n = 301;
    let (raw, up) = (values(3 * n, 7).iter().map(|v| 12.0 * v).collect::<Vec<f32>>(), values(3 * n, 8));
    let run = |device: Device| {
        let device = device.autodiff();
        let raw = Tensor::<2>::from_data(TensorData::new(raw.clone(), [n, 3]), &device).require_grad();
        let up = Tensor::<2>::from_data(TensorData::new(up.clone(), [n, 3]), &device);
        let out = bounded_scale(raw.clone(), 0.05, 5.0);
        let grads = (out.clone() * up).sum().backward();
        (host_vec(out), host_vec(raw.grad(&grads).unwrap()))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert_close("bounded scale forward", &a.0, &b.0);
    assert_close("bounded scale backward", &a.1, &b.1);
}

#[test]
fn fused_linear_on_wgpu_matches_cpu() {
    let Some(gpu) = wgpu_or_skip("fused linear") else { return };
    // Rows within one chunk of the weight-gradient sums, and over several with a partial last.
    for n in [97, 600] {
        fused_linear_matches_with(gpu.clone(), n);
    }
}

fn fused_linear_matches_with(gpu: Device, n: usize) {
    let (i, o) = (12, 8);
    let (x, wt, b, up) = (values(n * i, 3), values(i * o, 4), values(o, 5), values(n * o, 6));
    let run = |device: Device, act: Activation| {
        let device = device.autodiff();
        let x = Tensor::<2>::from_data(TensorData::new(x.clone(), [n, i]), &device).require_grad();
        let w = Tensor::<2>::from_data(TensorData::new(wt.clone(), [i, o]), &device).require_grad();
        let b = Tensor::<1>::from_data(TensorData::new(b.clone(), [o]), &device).require_grad();
        let up = Tensor::<2>::from_data(TensorData::new(up.clone(), [n, o]), &device);
        let out = fused_linear(x.clone(), w.clone(), b.clone(), act);
        let grads = (out.clone() * up).sum().backward();
        [
            host_vec(out),
            host_vec(x.grad(&grads).unwrap()),
            host_vec(w.grad(&grads).unwrap()),
            host_vec(b.grad(&grads).unwrap().reshape([1, o])),
        ]
    };
    for act in [Activation::Relu, Activation::Softplus, Activation::Identity] {
        let (a, b) = (run(Device::ndarray(), act), run(gpu.clone(), act));
        for (k, name) in ["output", "x", "weight", "bias"].iter().enumerate() {
            assert_close(&format!("{name} ({act:?}, {n} rows)"), &a[k], &b[k]);
        }
    }
}

#[test]
fn ssim_on_wgpu_matches_cpu() {
    let Some(gpu) = wgpu_or_skip("SSIM") else { return };
    let [v, h, w] = [2, 23, 29];
    let unit = |d: Vec<f32>| d.into_iter().map(|a| 0.5 * (a + 1.0)).collect::<Vec<f32>>();
    let (x, y) = (unit(values(v * h * w, 7)), unit(values(v * h * w, 8)));
    let run = |device: Device| {
        let device = device.autodiff();
        let x = Tensor::<3>::from_data(TensorData::new(x.clone(), [v, h, w]), &device).require_grad();
        let y = Tensor::<3>::from_data(TensorData::new(y.clone(), [v, h, w]), &device);
        let mu_y = window_blur(y.clone());
        let syy = window_blur(y.clone() * y.clone()) - mu_y.clone() * mu_y.clone();
        let out = ssim_mean(x.clone(), y, mu_y, syy);
        let grads = out.clone().backward();
        (host_vec(out), host_vec(x.grad(&grads).unwrap()))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert_close("SSIM value", &a.0, &b.0);
    // The gradient's entries are O(1 / pixels): compare relative to their largest.
    let scale = a.1.iter().fold(0.0f32, |m, q| m.max(q.abs()));
    let worst = a.1.iter().zip(&b.1).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
    assert!(scale > 0.0 && worst <= 1e-3 * scale, "SSIM gradient: wgpu differs by {worst} (scale {scale})");
}

/// The L1 and SSIM means over more elements than one pass of the reductions' 256 workgroups
/// covers (each unit sums three strided rounds), against f64 sums of the same values.
#[test]
fn means_over_many_workgroups_match_f64_sums() {
    use ctadsa_ops::loss_op::l1_mean;
    let Some(gpu) = wgpu_or_skip("the L1 and SSIM means") else { return };
    let [v, h, w] = [2, 500, 601];
    let n = v * h * w;
    let unit = |d: Vec<f32>| d.into_iter().map(|a| 0.5 * (a + 1.0)).collect::<Vec<f32>>();
    let (x, y) = (unit(values(n, 41)), unit(values(n, 42)));
    let l1_f64 = x.iter().zip(&y).map(|(a, b)| (*a as f64 - *b as f64).abs()).sum::<f64>() / n as f64;
    let xt = Tensor::<3>::from_data(TensorData::new(x.clone(), [v, h, w]), &gpu);
    let yt = Tensor::<3>::from_data(TensorData::new(y.clone(), [v, h, w]), &gpu);
    let l1 = host_vec(l1_mean(xt, yt))[0] as f64;
    assert!((l1 - l1_f64).abs() <= 1e-5 * l1_f64, "L1 mean {l1} against {l1_f64}");
    // SSIM: the CPU op's mean against the GPU's over the same images.
    let ssim = |device: Device| {
        let x = Tensor::<3>::from_data(TensorData::new(x.clone(), [v, h, w]), &device);
        let y = Tensor::<3>::from_data(TensorData::new(y.clone(), [v, h, w]), &device);
        let mu_y = window_blur(y.clone());
        let syy = window_blur(y.clone() * y.clone()) - mu_y.clone() * mu_y.clone();
        host_vec(ssim_mean(x, y, mu_y, syy))[0] as f64
    };
    let (cpu, wgpu) = (ssim(Device::ndarray()), ssim(gpu));
    assert!((cpu - wgpu).abs() <= 1e-5 * cpu.abs().max(1e-3), "SSIM mean {wgpu} against the CPU's {cpu}");
}

#[test]
fn anchor_targets_on_wgpu_match_cpu() {
    use ctadsa_ops::anchor_op::grid::AnchorGrid;
    use ctadsa_ops::anchor_op::{DeviceGrid, anchor_targets};
    let Some(gpu) = wgpu_or_skip("anchor search") else { return };
    // Points on a tube of radius 1 mm along x, and queries around it.
    let pts: Vec<[f64; 3]> = (0..4000)
        .map(|i| {
            let (t, a) = (i as f64 * 0.005 - 10.0, i as f64 * 2.399);
            [t, a.cos(), a.sin()]
        })
        .collect();
    let q = values(3 * 1500, 11).iter().map(|v| 2.0 * v).collect::<Vec<f32>>();
    let grid = AnchorGrid::new(&pts, 0.5);
    let run = |device: Device| {
        let dg = DeviceGrid::new(&grid, 8, 0.5, &device);
        let queries = Tensor::<2>::from_data(TensorData::new(q.clone(), [1500, 3]), &device);
        let (t, k) = anchor_targets(queries, &dg);
        (host_vec(t), host_vec(k))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert_eq!(a.1, b.1, "anchored centres");
    assert!(a.1.contains(&1.0) && a.1.contains(&0.0), "a mix of anchored and free centres");
    assert_close("anchor targets", &a.0, &b.0);
}

/// The anchoring term as one op on wgpu (gather, search, one-workgroup reduction; scatter-add
/// backward) against the tensor-op composition on the CPU: the term and the centres' gradient,
/// with repeated samples and centres both anchored and free.
#[test]
fn anchor_loss_on_wgpu_matches_the_composed_cpu_term() {
    use burn::tensor::Int;
    use ctadsa_ops::anchor_op::grid::AnchorGrid;
    use ctadsa_ops::anchor_op::{DeviceGrid, anchor_loss};
    let Some(gpu) = wgpu_or_skip("anchor loss") else { return };
    let pts: Vec<[f64; 3]> = (0..4000)
        .map(|i| {
            let (t, a) = (i as f64 * 0.005 - 10.0, i as f64 * 2.399);
            [t, a.cos(), a.sin()]
        })
        .collect();
    let n = 700;
    let means = values(3 * n, 21).iter().map(|v| 2.0 * v).collect::<Vec<f32>>();
    // 1,500 samples of 700 centres (with repeats), more than one workgroup's 256 units.
    let sample: Vec<i64> = (0..1500).map(|j| (j * 7919 % n) as i64).collect();
    let grid = AnchorGrid::new(&pts, 0.5);
    let run = |device: Device| {
        let device = device.autodiff();
        let dg = DeviceGrid::new(&grid, 8, 0.5, &device);
        let means = Tensor::<2>::from_data(TensorData::new(means.clone(), [n, 3]), &device).require_grad();
        let sample = Tensor::<1, Int>::from_data(TensorData::new(sample.clone(), [sample.len()]), &device);
        let loss = anchor_loss(means.clone(), sample, &dg).mul_scalar(3.0);
        let grads = loss.backward();
        (host_vec(loss), host_vec(means.grad(&grads).unwrap()))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert!(a.0[0] > 0.0 && a.1.contains(&0.0) && a.1.iter().any(|g| *g != 0.0), "{:?}", a.0);
    assert_close("anchor loss", &a.0, &b.0);
    assert_close("anchor loss gradient", &a.1, &b.1);
}

/// The loss's pieces as ops on wgpu (the L1 mean in one workgroup, the total of L1, SSIM and
/// further terms) against their tensor-op composition on the CPU: values and gradients, with pixels where the
/// images agree (the gradient of |x − y| is 0 there).
#[test]
fn loss_terms_on_wgpu_match_the_composed_cpu_terms() {
    use ctadsa_ops::loss_op::{l1_mean, total_loss};
    let Some(gpu) = wgpu_or_skip("loss terms") else { return };
    let [v, h, w] = [3, 37, 41];
    let x = values(v * h * w, 31);
    let mut y = values(v * h * w, 32);
    for i in (0..y.len()).step_by(5) {
        y[i] = x[i];
    }
    let run = |device: Device| {
        let device = device.autodiff();
        let xt = Tensor::<3>::from_data(TensorData::new(x.clone(), [v, h, w]), &device).require_grad();
        let yt = Tensor::<3>::from_data(TensorData::new(y.clone(), [v, h, w]), &device);
        let s = Tensor::<1>::from_data(TensorData::new(vec![0.8f32], [1]), &device).require_grad();
        let pa = Tensor::<1>::from_data(TensorData::new(vec![0.3f32], [1]), &device).require_grad();
        let fn_term = Tensor::<1>::from_data(TensorData::new(vec![0.6f32], [1]), &device).require_grad();
        let l1 = l1_mean(xt.clone(), yt);
        // The mix alone, with one term (one op on wgpu) and with two (the first composed).
        let mix = total_loss(l1.clone(), s.clone(), 0.2, vec![]);
        let one = total_loss(l1.clone(), s.clone(), 0.2, vec![(pa.clone(), 0.5)]);
        let two = total_loss(l1.clone(), s.clone(), 0.2, vec![(fn_term.clone(), 1.5), (pa.clone(), 0.5)]);
        let total = mix.clone().mul_scalar(3.0) + one.clone().mul_scalar(2.0) + two.clone();
        let grads = total.backward();
        let mut out = host_vec(l1);
        for t in [mix, one, two, s.grad(&grads).unwrap(), pa.grad(&grads).unwrap(), fn_term.grad(&grads).unwrap()] {
            out.extend(host_vec(t));
        }
        (out, host_vec(xt.grad(&grads).unwrap()))
    };
    let (a, b) = (run(Device::ndarray()), run(gpu));
    assert!(a.1.contains(&0.0) && a.1.iter().any(|g| *g > 0.0) && a.1.iter().any(|g| *g < 0.0));
    assert_close("L1, the totals, the terms' gradients", &a.0, &b.0);
    assert_close("L1 gradient", &a.1, &b.1);
}

/// The fused Adam kernel against the CPU loop: several steps, with and without the coupled L2
/// penalty, from the first step's zero moments on.
#[test]
fn fused_adam_on_wgpu_matches_cpu() {
    use burn::optim::Optimizer;
    use ctadsa_ops::optim::FusedAdam;
    let Some(gpu) = wgpu_or_skip("fused Adam") else { return };
    let n = 1000;
    for decay in [None, Some(0.01)] {
        let run = |device: Device| {
            let adam = FusedAdam::new(1e-8).with_weight_decay(decay);
            let mut p = Tensor::<1>::from_data(TensorData::new(values(n, 21), [n]), &device);
            let mut state = None;
            for step in 0..4u64 {
                let g = Tensor::<1>::from_data(TensorData::new(values(n, 30 + step), [n]), &device);
                let (next, s) = adam.step(1e-2, p, g, state);
                p = next;
                state = s;
            }
            let s = state.expect("state after a step");
            (host_vec(p), host_vec(s.moment_1), host_vec(s.moment_2))
        };
        let (a, b) = (run(Device::ndarray()), run(gpu.clone()));
        for (name, x, y) in [("parameter", &a.0, &b.0), ("first moment", &a.1, &b.1), ("second moment", &a.2, &b.2)] {
            // Relative to the largest value (the moments are far below 1).
            let scale = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let worst = x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            assert!(
                scale > 0.0 && worst <= 1e-5 * scale,
                "{name} ({decay:?}): wgpu differs by {worst} (scale {scale})"
            );
        }
    }
}

/// The whole opacity field as one op on wgpu (`field_op`) against its composition of the
/// encoding and linear-layer ops on the CPU: densities and the gradients of the positions, the
/// tables and every layer, with points outside the box (clamped) and a partial last chunk of
/// the weight-gradient sums.
#[test]
fn fused_field_on_wgpu_matches_the_composed_cpu_field() {
    let Some(gpu) = wgpu_or_skip("fused field") else { return };
    // A narrow MLP (units left idle) and the width the method trains.
    for hidden in [16, 64] {
        fused_field_matches_with(gpu.clone(), hidden);
    }
}

fn fused_field_matches_with(gpu: Device, hidden: usize) {
    use ctadsa_ops::field_op::{FieldSpec, Layer, field_densities};
    use ctadsa_ops::hash_grid::HashGridConfig;
    // Two dense levels and two hashed ones.
    let grid = HashGridConfig {
        levels: 4,
        features: 2,
        log2_table: 9,
        base_resolution: 3.0,
        growth: 2.0,
        ..Default::default()
    };
    let (n, width) = (700, grid.output_dim());
    let positions: Vec<f32> = values(3 * n, 31).iter().map(|v| 6.0 * v + 1.0).collect();
    let tables: Vec<f32> = values(grid.features * grid.rows(), 32);
    let shapes = [(width, hidden), (hidden, hidden), (hidden, 1)];
    let weights: Vec<Vec<f32>> = shapes
        .iter()
        .enumerate()
        .map(|(k, &(i, o))| values(i * o, 40 + k as u64).iter().map(|v| v * 2.0 / (i as f32).sqrt()).collect())
        .collect();
    let mut biases: Vec<Vec<f32>> = shapes
        .iter()
        .enumerate()
        .map(|(k, &(_, o))| values(o, 50 + k as u64).iter().map(|v| v * 0.1).collect())
        .collect();
    // Some densities on each side of the output ReLU's kink.
    biases[2] = vec![0.2];
    let up = values(n, 33);
    for output in [Activation::Softplus, Activation::Relu] {
        let spec = FieldSpec { min_mm: [-4.0, -5.0, -3.0], inv_size: [0.1, 0.125, 0.09], grid, output };
        let run = |device: Device| {
            let device = device.autodiff();
            let p = Tensor::<2>::from_data(TensorData::new(positions.clone(), [n, 3]), &device).require_grad();
            let t = Tensor::<2>::from_data(TensorData::new(tables.clone(), [grid.features, grid.rows()]), &device)
                .require_grad();
            let layers: Vec<Layer> = shapes
                .iter()
                .enumerate()
                .map(|(k, &(i, o))| Layer {
                    weight: Tensor::from_data(TensorData::new(weights[k].clone(), [i, o]), &device).require_grad(),
                    bias: Tensor::from_data(TensorData::new(biases[k].clone(), [o]), &device).require_grad(),
                })
                .collect();
            let out = field_densities(p.clone(), t.clone(), &layers, &spec);
            let up = Tensor::<1>::from_data(TensorData::new(up.clone(), [n]), &device);
            let grads = (out.clone() * up).sum().backward();
            let mut all = vec![host_vec(out), host_vec(p.grad(&grads).unwrap()), host_vec(t.grad(&grads).unwrap())];
            for l in &layers {
                all.push(host_vec(l.weight.grad(&grads).unwrap()));
                all.push(host_vec(l.bias.grad(&grads).unwrap()));
            }
            all
        };
        let (a, b) = (run(Device::ndarray()), run(gpu.clone()));
        let names =
            ["densities", "positions", "tables", "weight 0", "bias 0", "weight 1", "bias 1", "weight 2", "bias 2"];
        for (k, name) in names.iter().enumerate() {
            assert!(a[k].iter().any(|v| *v != 0.0), "{name} ({output:?}): all zero on the CPU");
            assert_close(&format!("field {name} ({output:?}, H = {hidden})"), &a[k], &b[k]);
        }
    }
}
