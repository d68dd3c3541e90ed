//! `[optim]`: learning rates and the Adam step.

use serde::{Deserialize, Serialize};

/// A learning rate decaying exponentially from `[0]` to `[1]` over the run.
pub type LrRange = [f64; 2];

/// `[optim]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Centres (mm per step; reference: 1e-4 × 200 mm).
    pub lr_means: LrRange,
    pub lr_scales: LrRange,
    pub lr_rotations: LrRange,
    pub lr_field: LrRange,
    /// Adam ε (reference 1e-15).
    pub epsilon: f64,
    /// Coupled L2 weight decay on the field (Adam's `weight_decay`; the reference's is 5e-5).
    /// 0 by default: with Adam it collapses the field to one density for every Gaussian once the
    /// image gradients are small (the paper configuration's field on BG0002 by iteration 5,000;
    /// `crate::method::field_health`, docs/RESULTS.md).
    pub field_weight_decay: f64,
    /// Which Adam: `fused` (one pass per parameter, [`ctadsa_ops::optim::FusedAdam`]) or `burn`
    /// (burn's `Adam`, the reference); the same update rule and checkpoint format.
    pub adam: AdamImpl,
}

/// Implementation of the Adam step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AdamImpl {
    #[default]
    Fused,
    Burn,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            lr_means: [0.02, 0.002],
            lr_scales: [5e-3, 5e-4],
            lr_rotations: [1e-3, 1e-4],
            lr_field: [1e-3, 1e-4],
            epsilon: 1e-15,
            field_weight_decay: 0.0,
            adam: AdamImpl::Fused,
        }
    }
}
