//! Adaptive density control: clone small / split large Gaussians whose projected centres get a
//! large mean gradient, prune those with (almost) no density or outside the working box — and
//! keep every parameter and both Adam moments consistent when the number of Gaussians changes:
//! kept Gaussians keep their values and moments, new ones start with zero moments (as 3DGS).
// Index loops over parallel arrays read more plainly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use std::collections::HashSet;

use burn::module::Param;
use burn::optim::ModuleOptimizer;
use burn::tensor::Device;
use glam::{DQuat, DVec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::config::DensifyConfig;
use crate::data::projector::noise::standard_normal;
use crate::data::volume::BoxMm;
use crate::error::Result;
use crate::method::model::{GaussianInit, GaussianModel, ScaleBounds, tensor2};
use ctadsa_ops::optim::state_edit::edit_state;

/// Per-Gaussian accumulators of the screen-space gradient statistic.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DensifyStats {
    /// Σ over renders of the NDC projected-centre gradient norm.
    pub sum: Vec<f32>,
    /// Number of renders in which the Gaussian was visible.
    pub count: Vec<f32>,
}

impl DensifyStats {
    /// Zeroed accumulators for `n` Gaussians.
    pub fn new(n: usize) -> Self {
        Self { sum: vec![0.0; n], count: vec![0.0; n] }
    }

    /// The accumulators as a device tensor `[n, 2]` (sum, visible count), the layout of the
    /// probe gradient, so that a step adds its gradient on the device.
    pub fn to_tensor(&self, device: &Device) -> burn::tensor::Tensor<2> {
        let n = self.sum.len().min(self.count.len());
        let flat: Vec<f32> = (0..n).flat_map(|i| [self.sum[i], self.count[i]]).collect();
        ctadsa_ops::readback::count_upload(flat.len());
        burn::tensor::Tensor::from_data(burn::tensor::TensorData::new(flat, [n, 2]), device)
    }

    /// Accumulators from `[n·2]` values laid out as [`DensifyStats::to_tensor`].
    pub fn from_interleaved(values: &[f32]) -> Self {
        let (sum, count) = values.chunks_exact(2).map(|c| (c[0], c[1])).unzip();
        Self { sum, count }
    }

    /// Adds the probe gradient `[n·2]` (sum, visible count) of one step.
    pub fn add(&mut self, probe_grad: &[f32]) {
        for (i, c) in probe_grad.chunks_exact(2).enumerate() {
            if let (Some(s), Some(n)) = (self.sum.get_mut(i), self.count.get_mut(i)) {
                *s += c[0];
                *n += c[1];
            }
        }
    }

    /// Mean statistic per Gaussian (0 where never visible).
    pub fn mean(&self) -> Vec<f32> {
        self.sum.iter().zip(&self.count).map(|(s, c)| if *c > 0.0 { s / c } else { 0.0 }).collect()
    }
}

/// What to do at one densification step.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DensifyPlan {
    /// Indices of the current Gaussians that stay, in order.
    pub keep: Vec<usize>,
    /// Gaussians appended after the kept ones.
    pub added: GaussianInit,
    pub cloned: usize,
    pub split: usize,
    pub pruned: usize,
}

/// Decides clones, splits and prunes from host copies of the parameters.
#[allow(clippy::too_many_arguments)]
pub fn plan(
    params: &GaussianInit,
    densities: &[f32],
    stats: &DensifyStats,
    cfg: &DensifyConfig,
    bounds: ScaleBounds,
    working_box: &BoxMm,
    voxel_mm: f64,
    iteration: usize,
    seed: u64,
) -> DensifyPlan {
    let n = params.len();
    let mean = stats.mean();
    // Clone/split boundary pd·h, decaying exponentially from the first to the second value.
    let span = (cfg.until.saturating_sub(cfg.from)).max(1) as f64;
    let t = ((iteration.saturating_sub(cfg.from)) as f64 / span).clamp(0.0, 1.0);
    let [a, b] = cfg.clone_scale_voxels;
    let pd = a * (b / a).powf(t) * voxel_mm;
    let scale = |raw: f32| bounds.scale_mm(raw);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (iteration as u64).wrapping_mul(0x9E37_79B9));
    let mut out = DensifyPlan::default();
    // Candidates for growth, strongest first, so that a cap keeps the most useful ones.
    let mut grow: Vec<usize> = (0..n).filter(|&i| mean[i] as f64 >= cfg.grad_threshold).collect();
    grow.sort_by(|&x, &y| mean[y].total_cmp(&mean[x]));
    let mut remaining = cfg.max_gaussians.saturating_sub(n);
    let mut split_set = HashSet::new();
    for &i in &grow {
        let m = DVec3::new(params.means[3 * i] as f64, params.means[3 * i + 1] as f64, params.means[3 * i + 2] as f64);
        if !working_box.contains(m) {
            continue;
        }
        let raw = &params.raw_scales[3 * i..3 * i + 3];
        let s: [f32; 3] = [scale(raw[0]), scale(raw[1]), scale(raw[2])];
        let q = &params.rotations[4 * i..4 * i + 4];
        let max_s = s.iter().copied().fold(0.0f32, f32::max) as f64;
        if max_s <= pd {
            if remaining < 1 {
                continue;
            }
            remaining -= 1;
            out.added.means.extend_from_slice(&params.means[3 * i..3 * i + 3]);
            out.added.raw_scales.extend_from_slice(raw);
            out.added.rotations.extend_from_slice(q);
            out.cloned += 1;
        } else {
            // Two children replace the parent: the net growth is one.
            if remaining < 1 {
                continue;
            }
            remaining -= 1;
            let rot = DQuat::from_xyzw(q[1] as f64, q[2] as f64, q[3] as f64, q[0] as f64).normalize();
            for _ in 0..2 {
                let local = DVec3::new(
                    standard_normal(&mut rng) * s[0] as f64,
                    standard_normal(&mut rng) * s[1] as f64,
                    standard_normal(&mut rng) * s[2] as f64,
                );
                let p = m + rot * local;
                out.added.means.extend([p.x as f32, p.y as f32, p.z as f32]);
                out.added.raw_scales.extend(s.map(|v| bounds.inverse(v / 1.6)));
                out.added.rotations.extend_from_slice(q);
            }
            split_set.insert(i);
            out.split += 1;
        }
    }
    for i in 0..n {
        let m = DVec3::new(params.means[3 * i] as f64, params.means[3 * i + 1] as f64, params.means[3 * i + 2] as f64);
        let dead = !(densities[i] as f64 >= cfg.min_density) || !working_box.contains(m) || !m.is_finite();
        if split_set.contains(&i) || dead {
            if dead {
                out.pruned += 1;
            }
            continue;
        }
        out.keep.push(i);
    }
    out
}

/// Gathers rows `keep` of a row-major `[n, cols]` array and appends `added`.
pub fn gather_rows(data: &[f32], cols: usize, keep: &[usize], added: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(keep.len() * cols + added.len());
    for &i in keep {
        out.extend_from_slice(&data[i * cols..(i + 1) * cols]);
    }
    out.extend_from_slice(added);
    out
}

/// Applies a plan to the model (same parameter ids, new values) and to Adam's state (moments of
/// kept Gaussians kept, zeros for new ones). Returns the model and optimizer.
pub fn apply(
    model: GaussianModel,
    optim: ModuleOptimizer,
    plan: &DensifyPlan,
    device: &Device,
) -> Result<(GaussianModel, ModuleOptimizer)> {
    let current = model.to_init();
    let n_new = plan.added.len();
    let ids = [
        (model.means.id, 3usize, &current.means, &plan.added.means),
        (model.raw_scales.id, 3, &current.raw_scales, &plan.added.raw_scales),
        (model.rotations.id, 4, &current.rotations, &plan.added.rotations),
    ];
    // Moments of kept Gaussians kept (row gather), zeros for the new ones.
    let optim = edit_state(optim, |t| {
        let (_, cols, ..) = ids.iter().find(|(id, ..)| id.val() == t.param_id)?;
        (t.shape.len() == 2).then(|| {
            let rows = gather_rows(&t.values, *cols, &plan.keep, &vec![0.0f32; n_new * cols]);
            let n_rows = rows.len() / cols;
            (rows, vec![n_rows, *cols])
        })
    })?;
    let [(id_m, _, m, am), (id_s, _, s, as_), (id_r, _, r, ar)] = ids;
    let model = GaussianModel {
        means: Param::initialized(id_m, tensor2(gather_rows(m, 3, &plan.keep, am), 3, device).require_grad()),
        raw_scales: Param::initialized(id_s, tensor2(gather_rows(s, 3, &plan.keep, as_), 3, device).require_grad()),
        rotations: Param::initialized(id_r, tensor2(gather_rows(r, 4, &plan.keep, ar), 4, device).require_grad()),
        field: model.field,
        bounds: model.bounds,
    };
    Ok((model, optim))
}

#[cfg(test)]
mod tests {
    #![allow(deprecated)] // burn-ndarray is the CPU backend the tests use.
    use super::*;
    use crate::method::model::field::FieldConfig;
    use burn::lr_scheduler::constant::ConstantLr;
    use burn::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::{Tensor, TensorData};
    use ctadsa_ops::hash_grid::HashGridConfig;
    use ctadsa_ops::readback::host_vec;

    /// Adam moments of the parameter `id` as `(rows, moment 1, moment 2)` (host copies).
    fn moments(optim: ModuleOptimizer, id: burn::module::ParamId) -> (ModuleOptimizer, Vec<Vec<f32>>) {
        let bytes = optim.into_bytes().unwrap();
        let reader = burn_pack::Reader::from_bytes(bytes.clone()).unwrap();
        let mut found = Vec::new();
        for t in reader.into_tensors().unwrap() {
            let (_, _, _, pid, b) = t.into_parts().unwrap();
            if pid == Some(id.val()) {
                found.push(b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect());
            }
        }
        let optim = AdamConfig::new().init().from_bytes(bytes).unwrap();
        (optim, found)
    }

    #[test]
    fn apply_keeps_values_and_moments_of_kept_gaussians_and_zeroes_new_moments() {
        let device = Device::ndarray().autodiff();
        let n = 5;
        let init = GaussianInit {
            means: (0..3 * n).map(|i| i as f32 * 0.5).collect(),
            raw_scales: (0..3 * n).map(|i| (i as f32 * 0.1).sin()).collect(),
            rotations: (0..n).flat_map(|i| [1.0, 0.1 * i as f32, 0.0, 0.0]).collect(),
        };
        let small = FieldConfig {
            encoding: HashGridConfig {
                levels: 2,
                features: 2,
                log2_table: 8,
                base_resolution: 4.0,
                growth: 1.5,
                ..Default::default()
            },
            hidden: 8,
            hidden_layers: 1,
            ..FieldConfig::default()
        };
        let field = GaussianModel::new_field(&small, [0.0; 3], [10.0; 3], 1.0, 3, &device);
        let model = GaussianModel::new(&init, field, ScaleBounds::from_voxel(0.5, 0.1, 10.0), &device);
        let mut optim = AdamConfig::new().init();
        // Two steps with a loss that gives every row a different gradient.
        let mut model = model;
        for _ in 0..2 {
            let w = Tensor::<2>::from_data(
                TensorData::new((0..3 * n).map(|i| 1.0 + i as f32).collect::<Vec<_>>(), [n, 3]),
                &device,
            );
            let loss = (model.means.val() * w.clone()).powi_scalar(2).sum()
                + (model.raw_scales.val() * w).sum()
                + model.rotations.val().powi_scalar(2).sum()
                + model.field.forward(model.means.val()).sum();
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            let lr = ModuleLrScheduler::new(ConstantLr::new(0.01)).step();
            model = optim.step(lr, model, grads);
        }
        let before_means = host_vec(model.means.val());
        let id = model.means.id;
        let (optim, before_moments) = moments(optim, id);
        assert_eq!(before_moments.len(), 2, "Adam keeps two moments for the centres");

        let plan = DensifyPlan {
            keep: vec![0, 2, 4],
            added: GaussianInit {
                means: vec![9.0, 9.0, 9.0, 8.0, 8.0, 8.0],
                raw_scales: vec![0.0; 6],
                rotations: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            },
            ..DensifyPlan::default()
        };
        let (model, optim) = apply(model, optim, &plan, &device).unwrap();
        assert_eq!(model.len(), 5);
        assert_eq!(model.means.val().dims(), [5, 3]);
        assert_eq!(model.raw_scales.val().dims(), [5, 3]);
        assert_eq!(model.rotations.val().dims(), [5, 4]);
        let after_means = host_vec(model.means.val());
        for (row, &old) in plan.keep.iter().enumerate() {
            assert_eq!(after_means[3 * row..3 * row + 3], before_means[3 * old..3 * old + 3]);
        }
        assert_eq!(after_means[9..], [9.0, 9.0, 9.0, 8.0, 8.0, 8.0]);
        let (mut optim, after_moments) = moments(optim, model.means.id);
        for (before, after) in before_moments.iter().zip(&after_moments) {
            assert_eq!(after.len(), 15);
            for (row, &old) in plan.keep.iter().enumerate() {
                assert_eq!(after[3 * row..3 * row + 3], before[3 * old..3 * old + 3]);
                assert!(after[3 * row..3 * row + 3].iter().any(|v| *v != 0.0), "kept moments are non-zero");
            }
            assert!(after[9..].iter().all(|v| *v == 0.0), "new Gaussians start with zero moments");
        }
        // The optimizer keeps working on the new shapes.
        let loss = model.means.val().powi_scalar(2).sum() + model.field.forward(model.means.val()).sum();
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        let lr = ModuleLrScheduler::new(ConstantLr::new(0.01)).step();
        let model = optim.step(lr, model, grads);
        assert_eq!(model.means.val().dims(), [5, 3]);
    }

    /// Four Gaussians: small and strongly pulled (cloned), large and strongly pulled (split into
    /// two), faded (pruned), outside the working box (pruned); one quiet one stays as it is.
    #[test]
    fn plan_clones_small_splits_large_and_prunes_faded_or_outside() {
        let bounds = ScaleBounds::from_voxel(0.5, 0.1, 10.0);
        let raw = |s: f32| bounds.inverse(s);
        let centres = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [50.0, 0.0, 0.0], [3.0, 0.0, 0.0]];
        let sizes = [0.2f32, 3.0, 0.2, 0.2, 0.2];
        let params = GaussianInit {
            means: centres.iter().flatten().copied().collect(),
            raw_scales: sizes.iter().flat_map(|&s| [raw(s); 3]).collect(),
            rotations: [1.0f32, 0.0, 0.0, 0.0].repeat(5),
        };
        let densities = [1.0f32, 1.0, 1e-9, 1.0, 1.0];
        let mut stats = DensifyStats::new(5);
        stats.add(&[5e-3, 1.0, 5e-3, 1.0, 1e-6, 1.0, 5e-3, 1.0, 1e-6, 1.0]);
        let cfg = DensifyConfig { from: 0, until: 100, grad_threshold: 1e-4, ..DensifyConfig::default() };
        let working_box = BoxMm { min_mm: [-10.0; 3], max_mm: [10.0; 3] };
        let plan = plan(&params, &densities, &stats, &cfg, bounds, &working_box, 0.5, 0, 1);
        assert_eq!((plan.cloned, plan.split, plan.pruned), (1, 1, 2), "{plan:?}");
        // Kept: the clone's parent and the quiet one; the split parent and both pruned are gone.
        assert_eq!(plan.keep, vec![0, 4]);
        assert_eq!(plan.added.len(), 3, "one clone and two children");
        assert_eq!(&plan.added.means[..3], &centres[0], "a clone starts on its parent");
        let child_scale = bounds.inverse(3.0 / 1.6);
        for &r in &plan.added.raw_scales[3..] {
            assert!((r - child_scale).abs() < 1e-4, "children are 1.6 times smaller: raw {r} vs {child_scale}");
        }
        for child in plan.added.means[3..].chunks(3) {
            let d = ((child[0] - 1.0).powi(2) + child[1].powi(2) + child[2].powi(2)).sqrt();
            assert!(d < 4.0 * 3.0, "a child {d} mm from its parent, scale 3 mm");
        }
        // The cap: no room left means no growth, but pruning still happens.
        let capped = DensifyConfig { max_gaussians: 5, ..cfg };
        let plan = super::plan(&params, &densities, &stats, &capped, bounds, &working_box, 0.5, 0, 1);
        assert_eq!((plan.cloned, plan.split, plan.pruned), (0, 0, 2));
        assert_eq!(plan.keep, vec![0, 1, 4]);
    }
}
