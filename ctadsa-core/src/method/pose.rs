//! Per-view pose refinement: a small rigid correction of each view (3 rotation + 3 translation
//! parameters), learned jointly with the Gaussians through the renderer's gradients, absorbs
//! the error of a 2-D/3-D registration or of the C-arm's angle readout.
//!
//! Convention: view `v` with correction `(ω_v, t_v)` sees a world point `x` where the nominal
//! view would see `R(ω_v) x + t_v` — a rotation about the isocentre (the world origin) by the
//! axis-angle vector `ω_v` (rad) followed by a translation `t_v` (mm). Rendering with the
//! correction is rendering the Gaussians moved by it (means `R μ + t`, rotations `q_R ⊗ q`), so
//! the renderer's own gradients reach the pose through burn's autodiff.

use burn::module::{Module, Param};
use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_render::Gaussians;

use crate::data::projector::correction::PoseCorrection;
use ctadsa_ops::readback::host_vec;

/// The corrections of all views as burn parameters.
#[derive(Module, Debug)]
pub struct ViewPoses {
    /// Axis-angle rotations `[V, 3]` (rad) about the isocentre.
    pub rotations_rad: Param<Tensor<2>>,
    /// Translations `[V, 3]` (mm), applied after the rotation.
    pub translations_mm: Param<Tensor<2>>,
    /// 1 for a view whose pose is refined, 0 for a view held fixed.
    #[module(skip)]
    pub free: Vec<f32>,
}

/// `[ω]×` as a linear function of `ω`: row `i` is the flattened 3 × 3 generator of axis `i`.
const CROSS_GENERATORS: [f32; 27] = [
    0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0, // x
    0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, // y
    0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, // z
];

/// The left-multiplication matrix `L(p)` (`p ⊗ q = L(p) q`, wxyz) as a linear function of `p`:
/// row `k` is the flattened 4 × 4 coefficient of `p_k`.
const QUAT_LEFT_GENERATORS: [f32; 64] = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, // w
    0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, // x
    0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, // y
    0.0, 0.0, 0.0, -1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, // z
];

impl ViewPoses {
    /// Zero corrections for `views` views; the views in `fixed` never move.
    pub fn new(views: usize, fixed: &[usize], device: &Device) -> Self {
        let zeros = || Param::from_tensor(Tensor::<2>::zeros([views, 3], device));
        let free = (0..views).map(|v| if fixed.contains(&v) { 0.0 } else { 1.0 }).collect();
        Self { rotations_rad: zeros(), translations_mm: zeros(), free }
    }

    /// Starts from given corrections (e.g. to test or to continue a refinement).
    pub fn from_corrections(corrections: &[PoseCorrection], fixed: &[usize], device: &Device) -> Self {
        let v = corrections.len();
        let pick = |range: std::ops::Range<usize>| {
            let data: Vec<f32> = corrections.iter().flat_map(|c| c[range.clone()].iter().map(|&x| x as f32)).collect();
            Param::from_tensor(Tensor::<2>::from_data(TensorData::new(data, [v, 3]), device))
        };
        let free = (0..v).map(|i| if fixed.contains(&i) { 0.0 } else { 1.0 }).collect();
        Self { rotations_rad: pick(0..3), translations_mm: pick(3..6), free }
    }

    /// Number of views.
    pub fn len(&self) -> usize {
        self.free.len()
    }

    /// Whether there is no view.
    pub fn is_empty(&self) -> bool {
        self.free.is_empty()
    }

    /// The Gaussians as view `view` sees them through its correction (differentiable in the
    /// Gaussians and in this view's correction).
    pub fn apply(&self, gaussians: &Gaussians, view: usize) -> Gaussians {
        let device = gaussians.means.device();
        let free = self.free[view];
        let omega = self.rotations_rad.val().slice([view..view + 1, 0..3]).mul_scalar(free);
        let t = self.translations_mm.val().slice([view..view + 1, 0..3]).mul_scalar(free);
        let (rotation, quaternion) = rotation_and_quaternion(omega, &device);
        let means = gaussians.means.clone().matmul(rotation.transpose()) + t;
        let left = quaternion.matmul(constant(&QUAT_LEFT_GENERATORS, [4, 16], &device)).reshape([4, 4]);
        let rotations = gaussians.rotations.clone().matmul(left.transpose());
        Gaussians { means, scales: gaussians.scales.clone(), rotations, densities: gaussians.densities.clone() }
    }

    /// The current corrections on the host.
    pub fn corrections(&self) -> Vec<PoseCorrection> {
        let r = host_vec(self.rotations_rad.val());
        let t = host_vec(self.translations_mm.val());
        (0..self.len())
            .map(|v| {
                let f = self.free[v] as f64;
                let g = |a: &[f32], k: usize| a[3 * v + k] as f64 * f;
                [g(&r, 0), g(&r, 1), g(&r, 2), g(&t, 0), g(&t, 1), g(&t, 2)]
            })
            .collect()
    }
}

fn constant<const D: usize>(values: &[f32], shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values.to_vec(), shape), device)
}

/// Rotation matrix `[3, 3]` and unit quaternion `[1, 4]` (wxyz) of the axis-angle `omega`
/// `[1, 3]`, by their Taylor series in `θ² = |ω|²` to `θ⁴` (smooth at 0; the truncation error
/// is below 1e-7 for θ ≤ 0.2 rad ≈ 11°, far beyond a registration error).
fn rotation_and_quaternion(omega: Tensor<2>, device: &Device) -> (Tensor<2>, Tensor<2>) {
    let theta2 = omega.clone().powi_scalar(2).sum_dim(1); // [1, 1]
    let theta4 = theta2.clone().powi_scalar(2);
    let series =
        |c0: f32, c2: f32, c4: f32| theta2.clone().mul_scalar(c2).add(theta4.clone().mul_scalar(c4)).add_scalar(c0);
    let a = series(1.0, -1.0 / 6.0, 1.0 / 120.0); // sin θ / θ
    let b = series(0.5, -1.0 / 24.0, 1.0 / 720.0); // (1 − cos θ) / θ²
    let k = omega.clone().matmul(constant(&CROSS_GENERATORS, [3, 9], device)).reshape([3, 3]);
    let k2 = k.clone().matmul(k.clone());
    let rotation = Tensor::<2>::eye(3, device) + k.mul(a) + k2.mul(b);
    let w = series(1.0, -1.0 / 8.0, 1.0 / 384.0); // cos(θ/2)
    let s = series(0.5, -1.0 / 48.0, 1.0 / 3840.0); // sin(θ/2) / θ
    let quaternion = Tensor::cat(vec![w, omega.mul(s)], 1);
    (rotation, quaternion)
}
#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::projector::correction::apply_correction;
    use burn::tensor::Device;
    use glam::{DQuat, DVec3};

    fn device() -> Device {
        Device::default()
    }

    #[test]
    fn tensor_correction_matches_the_exact_rigid_motion() {
        let dev = device();
        let c: PoseCorrection = [0.03, -0.05, 0.02, 1.5, -2.0, 0.7];
        let means = [[10.0f32, -3.0, 4.0], [-20.0, 15.0, 1.0], [0.0, 0.0, 0.0]];
        let q0 = DQuat::from_scaled_axis(DVec3::new(0.3, 0.1, -0.4));
        let g = Gaussians {
            means: Tensor::from_data(TensorData::new(means.concat(), [3, 3]), &dev),
            scales: Tensor::ones([3, 3], &dev),
            rotations: Tensor::from_data(
                TensorData::new([q0.w, q0.x, q0.y, q0.z].repeat(3).iter().map(|&v| v as f32).collect(), [3, 4]),
                &dev,
            ),
            densities: Tensor::ones([3], &dev),
        };
        let poses = ViewPoses::from_corrections(&[[0.0; 6], c], &[], &dev);
        let moved = poses.apply(&g, 1);
        let m = host_vec(moved.means);
        for (i, p) in means.iter().enumerate() {
            let want = apply_correction(&c, DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
            for k in 0..3 {
                assert!(
                    (m[3 * i + k] as f64 - want[k]).abs() < 1e-4,
                    "mean {i} axis {k}: {} vs {}",
                    m[3 * i + k],
                    want[k]
                );
            }
        }
        let q = host_vec(moved.rotations);
        let want = DQuat::from_scaled_axis(DVec3::new(c[0], c[1], c[2])) * q0;
        let got = DQuat::from_xyzw(q[1] as f64, q[2] as f64, q[3] as f64, q[0] as f64).normalize();
        assert!(got.dot(want).abs() > 1.0 - 1e-7, "quaternion {got:?} vs {want:?}");
        // View 0 has a zero correction: identity.
        let same = host_vec(poses.apply(&g, 0).means);
        assert!(same.iter().zip(means.concat()).all(|(a, b)| (a - b).abs() < 1e-6));
    }

    #[test]
    fn fixed_views_do_not_move() {
        let dev = device();
        let poses = ViewPoses::from_corrections(&[[0.1, 0.0, 0.0, 5.0, 0.0, 0.0]], &[0], &dev);
        assert_eq!(poses.corrections()[0], [0.0; 6]);
    }
}
