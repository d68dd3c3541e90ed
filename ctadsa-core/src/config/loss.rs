//! `[loss]`: the loss terms and their weights.

use serde::{Deserialize, Serialize};

/// `[loss]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LossConfig {
    /// λ of `(1 − λ) L1 + λ (1 − SSIM)`.
    pub lambda_dssim: f64,
    pub fn_weight: f64,
    pub fn_start: usize,
    /// Vessel pixels for the FN loss: ≥ τ × the 99.5th percentile of the target's positives,
    /// and at least 3 × the view's estimated noise σ (`data::masks::NOISE_FLOOR_SIGMAS`).
    pub fn_tau: f64,
    pub fn_margin: f64,
    pub pa_weight: f64,
    pub pa_start: usize,
    /// Anchoring radius (mm) and neighbours.
    pub pa_radius_mm: f64,
    pub pa_k: usize,
    /// Gaussians sampled per step for the anchoring term (0 = all).
    pub pa_samples: usize,
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            lambda_dssim: 0.07,
            fn_weight: 1.5,
            fn_start: 4000,
            fn_tau: 0.01,
            fn_margin: 0.005,
            pa_weight: 0.0025,
            pa_start: 1000,
            pa_radius_mm: 0.5,
            pa_k: 8,
            pa_samples: 2048,
        }
    }
}
