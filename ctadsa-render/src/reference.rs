//! Slow, obvious f64 references the kernels are tested against. Nothing here is used by the
//! kernels; it restates the physics independently:
//!
//! - [`pixel_ray_tigre`]: a pixel's ray from TIGRE's physical detector description (detector
//!   centre, axes, offsets, row flip), not from pinhole intrinsics;
//! - [`line_integral_quadrature`]: the density integrated numerically along a ray
//!   (composite Simpson over ±12 standard deviations around the ray's density peak);
//! - [`line_integral_exact`]: the closed form `ρ sqrt(2π/a) exp(−½ eᵀQe)` in the direct
//!   (not conic) parametrisation, for finite differences.

use glam::{DMat3, DQuat, DVec3};

use crate::TigreGeometry;

/// One Gaussian in f64: centre (mm), scales (mm), quaternion `(w, x, y, z)` (any norm), density.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefGaussian {
    pub mean: [f64; 3],
    pub scale: [f64; 3],
    pub quat: [f64; 4],
    pub density: f64,
}

impl RefGaussian {
    /// The precision matrix `Q = R S⁻² Rᵀ`.
    pub fn precision(&self) -> DMat3 {
        let [w, x, y, z] = self.quat;
        let r = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
        let s = DMat3::from_diagonal(DVec3::from(self.scale.map(|v| 1.0 / (v * v))));
        r * s * r.transpose()
    }

    /// The density `ρ exp(−½ (x−μ)ᵀQ(x−μ))` at a point (mm).
    pub fn density_at(&self, x: DVec3, q: &DMat3) -> f64 {
        let d = x - DVec3::from(self.mean);
        self.density * (-0.5 * d.dot(*q * d)).exp()
    }

    /// Total mass `ρ (2π)^{3/2} s₁ s₂ s₃` (density × mm³).
    pub fn mass(&self) -> f64 {
        self.density * (2.0 * std::f64::consts::PI).powf(1.5) * self.scale.iter().product::<f64>()
    }
}

/// Source position and unit direction of the ray through the centre of pixel `(col, row)` of a
/// TIGRE detector (row 0 at the top, i.e. TIGRE's row `H−1−row`). Secondary angle must be 0.
pub fn pixel_ray_tigre(g: &TigreGeometry, col: f64, row: f64) -> (DVec3, DVec3) {
    assert!(g.secondary_deg == 0.0, "the physical reference covers secondary angle 0");
    let a = g.primary_deg.to_radians();
    let radial = DVec3::new(a.cos(), a.sin(), 0.0);
    let source = g.dso_mm * radial;
    let det_centre = -(g.dsd_mm - g.dso_mm) * radial;
    let e_u = DVec3::new(-a.sin(), a.cos(), 0.0);
    let e_z = DVec3::Z;
    let [w, h] = g.detector_px.map(|v| v as f64);
    let tigre_row = h - 1.0 - row;
    let pixel = det_centre
        + ((col - (w - 1.0) / 2.0) * g.pixel_mm[0] + g.offset_mm[0]) * e_u
        + ((tigre_row - (h - 1.0) / 2.0) * g.pixel_mm[1] + g.offset_mm[1]) * e_z;
    (source, (pixel - source).normalize())
}

/// Where a world point lands on a TIGRE detector, as `(col, row)` pixel coordinates (row 0 at
/// the top), by intersecting the source→point line with the detector plane. Secondary angle 0.
pub fn project_point_tigre(g: &TigreGeometry, p: DVec3) -> (f64, f64) {
    assert!(g.secondary_deg == 0.0, "the physical reference covers secondary angle 0");
    let a = g.primary_deg.to_radians();
    let radial = DVec3::new(a.cos(), a.sin(), 0.0);
    let source = g.dso_mm * radial;
    let det_centre = -(g.dsd_mm - g.dso_mm) * radial;
    let e_u = DVec3::new(-a.sin(), a.cos(), 0.0);
    let dir = p - source;
    // Plane: (x − det_centre)·radial = 0.
    let t = (det_centre - source).dot(radial) / dir.dot(radial);
    let hit = source + t * dir - det_centre;
    let [w, h] = g.detector_px.map(|v| v as f64);
    let col = (hit.dot(e_u) - g.offset_mm[0]) / g.pixel_mm[0] + (w - 1.0) / 2.0;
    let tigre_row = (hit.z - g.offset_mm[1]) / g.pixel_mm[1] + (h - 1.0) / 2.0;
    (col, h - 1.0 - tigre_row)
}

/// `∫ ρ exp(−½ (o + t d − μ)ᵀ Q (o + t d − μ)) dt` over the whole line by composite Simpson
/// (`intervals` even) on `t* ± 12 σ_t`, where `t*` and `σ_t` locate the density peak along
/// the ray (they only place the window). `dir` must be a unit vector.
pub fn line_integral_quadrature(g: &RefGaussian, origin: DVec3, dir: DVec3, intervals: usize) -> f64 {
    let q = g.precision();
    let mu = DVec3::from(g.mean);
    let a = dir.dot(q * dir);
    let t_peak = dir.dot(q * (mu - origin)) / a;
    let sigma_t = 1.0 / a.sqrt();
    let (t0, t1) = (t_peak - 12.0 * sigma_t, t_peak + 12.0 * sigma_t);
    let n = intervals + intervals % 2;
    let h = (t1 - t0) / n as f64;
    let f = |t: f64| g.density_at(origin + t * dir, &q);
    let mut sum = f(t0) + f(t1);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        sum += w * f(t0 + i as f64 * h);
    }
    sum * h / 3.0
}

/// The closed-form line integral in the direct stable form: `a = dᵀQd`, `t* = dᵀQ(μ−o)/a`,
/// `e = o + t* d − μ`, value `ρ sqrt(2π/a) exp(−½ eᵀQe)`. `dir` must be a unit vector.
pub fn line_integral_exact(g: &RefGaussian, origin: DVec3, dir: DVec3) -> f64 {
    let q = g.precision();
    let mu = DVec3::from(g.mean);
    let a = dir.dot(q * dir);
    let t_star = dir.dot(q * (mu - origin)) / a;
    let e = origin + t_star * dir - mu;
    g.density * (2.0 * std::f64::consts::PI / a).sqrt() * (-0.5 * e.dot(q * e)).exp()
}

/// Smallest Mahalanobis distance² between the ray and the Gaussian's centre (`eᵀQe` above):
/// the ray meets the k-σ ellipsoid iff this is ≤ k².
pub fn ray_mahalanobis2(g: &RefGaussian, origin: DVec3, dir: DVec3) -> f64 {
    let q = g.precision();
    let mu = DVec3::from(g.mean);
    let a = dir.dot(q * dir);
    let t_star = dir.dot(q * (mu - origin)) / a;
    let e = origin + t_star * dir - mu;
    e.dot(q * e)
}
