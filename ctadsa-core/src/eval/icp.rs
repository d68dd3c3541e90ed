//! Rigid point-to-point ICP (for `--icp` parity with the reference evaluation): each iteration
//! matches every source point to its nearest target point (k-d tree) and solves the best rigid
//! motion in closed form (Horn's quaternion method; the 4 × 4 eigenproblem by Jacobi rotations).
// Index loops over parallel arrays read more plainly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

use glam::{DMat3, DQuat, DVec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};

/// A rigid motion `x ↦ R x + t` (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    pub rotation: DMat3,
    pub translation_mm: DVec3,
}

impl Rigid {
    /// The identity.
    pub const IDENTITY: Self = Self { rotation: DMat3::IDENTITY, translation_mm: DVec3::ZERO };

    /// Applies the motion to a point.
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation_mm
    }

    /// `self ∘ first`.
    pub fn after(&self, first: &Rigid) -> Rigid {
        Rigid {
            rotation: self.rotation * first.rotation,
            translation_mm: self.rotation * first.translation_mm + self.translation_mm,
        }
    }
}

/// Eigenvector of the largest eigenvalue of a symmetric 4 × 4 matrix (cyclic Jacobi).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0f64; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..50 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..4 {
                    let (akp, akq) = (a[k][p], a[k][q]);
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..4 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let best = (0..4).max_by(|&i, &j| a[i][i].total_cmp(&a[j][j])).unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

/// The rigid motion minimising `Σ ‖R a_i + t − b_i‖²` over paired points (Horn 1987).
pub fn best_rigid(a: &[DVec3], b: &[DVec3]) -> Rigid {
    let n = a.len().min(b.len());
    if n == 0 {
        return Rigid::IDENTITY;
    }
    let ca = a[..n].iter().copied().sum::<DVec3>() / n as f64;
    let cb = b[..n].iter().copied().sum::<DVec3>() / n as f64;
    let mut s = [[0.0f64; 3]; 3];
    for (p, q) in a[..n].iter().zip(&b[..n]) {
        let (p, q) = ((*p - ca).to_array(), (*q - cb).to_array());
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += p[i] * q[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let nmat = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let [w, x, y, z] = top_eigenvector(nmat);
    let rotation = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
    Rigid { rotation, translation_mm: cb - rotation * ca }
}

/// Aligns `source` to `target` by trimmed ICP: each step fits the motion to the `keep` fraction
/// (0–1] of correspondences with the smallest distances (the reference keeps 0.8), at most
/// `iterations` steps, stopping when the mean distance changes by less than 1e-6 mm. Returns the
/// motion and the final mean distance over all source points (mm).
pub fn icp(source: &[DVec3], target: &[DVec3], iterations: usize, keep: f64) -> (Rigid, f64) {
    if source.is_empty() || target.is_empty() {
        return (Rigid::IDENTITY, f64::NAN);
    }
    let pts: Vec<[f64; 3]> = target.iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts).expect("non-empty, finite points");
    let mut total = Rigid::IDENTITY;
    let mut moved: Vec<DVec3> = source.to_vec();
    let mut last = f64::INFINITY;
    for _ in 0..iterations {
        let queries: Vec<[f64; 3]> = moved.iter().map(|p| p.to_array()).collect();
        let nearest = tree.query_batch(&queries).nearest_one::<SquaredEuclidean<f64>>().execute();
        let matched: Vec<DVec3> = nearest.iter().map(|r| target[r.item as usize]).collect();
        let mean = nearest.iter().map(|r| r.distance.sqrt()).sum::<f64>() / nearest.len() as f64;
        if (last - mean).abs() < 1e-6 {
            last = mean;
            break;
        }
        last = mean;
        let mut order: Vec<usize> = (0..moved.len()).collect();
        order.sort_by(|&i, &j| nearest[i].distance.total_cmp(&nearest[j].distance));
        order.truncate(((moved.len() as f64 * keep.clamp(0.0, 1.0)).ceil() as usize).max(3).min(moved.len()));
        let a: Vec<DVec3> = order.iter().map(|&i| moved[i]).collect();
        let b: Vec<DVec3> = order.iter().map(|&i| matched[i]).collect();
        let step = best_rigid(&a, &b);
        moved.iter_mut().for_each(|p| *p = step.apply(*p));
        total = step.after(&total);
    }
    (total, last)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Vec<DVec3> {
        // An asymmetric L-shaped cloud, so that the alignment is unique.
        let mut v = Vec::new();
        for i in 0..40 {
            v.push(DVec3::new(i as f64 * 0.5, 0.0, 0.0));
            v.push(DVec3::new(0.0, i as f64 * 0.3, (i % 5) as f64 * 0.2));
            v.push(DVec3::new(1.0, 2.0, i as f64 * 0.1));
        }
        v
    }

    #[test]
    fn best_rigid_recovers_a_known_motion() {
        let a = cloud();
        let truth = Rigid {
            rotation: DMat3::from_euler(glam::EulerRot::XYZ, 0.3, -0.2, 0.5),
            translation_mm: DVec3::new(1.0, -2.0, 3.0),
        };
        let b: Vec<DVec3> = a.iter().map(|p| truth.apply(*p)).collect();
        let got = best_rigid(&a, &b);
        assert!((got.translation_mm - truth.translation_mm).length() < 1e-9);
        assert!((got.rotation - truth.rotation).to_cols_array().iter().all(|d| d.abs() < 1e-9));
    }

    #[test]
    fn icp_undoes_a_small_misalignment() {
        let target = cloud();
        let motion = Rigid {
            rotation: DMat3::from_euler(glam::EulerRot::XYZ, 0.03, 0.02, -0.04),
            translation_mm: DVec3::new(0.3, -0.2, 0.1),
        };
        let source: Vec<DVec3> = target.iter().map(|p| motion.apply(*p)).collect();
        let (fit, residual) = icp(&source, &target, 100, 1.0);
        assert!(residual < 1e-6, "residual {residual} mm");
        let back = fit.apply(source[17]);
        assert!((back - target[17]).length() < 1e-6);
    }
}
