//! `[model]` and `[field]`: the Gaussians' scale bounds and the opacity field.

use serde::{Deserialize, Serialize};

use super::HashGridConfig;

/// `[model]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Scale bounds in working-grid voxels (paper: 0.1 and 10).
    pub scale_min_voxels: f64,
    pub scale_max_voxels: f64,
    /// Footprint cut-off (standard deviations).
    pub k_sigma: f32,
    /// Initial density of every Gaussian (density units, per mm); 0 = estimated from the images.
    pub initial_density: f64,
    /// GPU render kernels: units per Gaussian and view, each walking every `render_row_split`-th
    /// footprint row; 0 = by the detector's height (`ctadsa_render::RenderSettings::row_split`).
    /// Speed only: the images and gradients agree up to float rounding.
    pub render_row_split: u32,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self { scale_min_voxels: 0.1, scale_max_voxels: 10.0, k_sigma: 3.0, initial_density: 0.0, render_row_split: 0 }
    }
}

/// The MLP's output non-linearity (both non-negative).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputActivation {
    /// `max(0, x)`, as the reference implementation (can start or get stuck at zero).
    Relu,
    /// `ln(1 + eˣ)`: strictly positive, never stuck.
    Softplus,
}

/// `[field]`: the opacity field (hash encoding + MLP).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FieldConfig {
    pub encoding: HashGridConfig,
    /// Width of the hidden layers.
    pub hidden: usize,
    /// Number of hidden layers (1–4).
    pub hidden_layers: usize,
    pub output: OutputActivation,
}

impl Default for FieldConfig {
    fn default() -> Self {
        Self { encoding: HashGridConfig::default(), hidden: 64, hidden_layers: 2, output: OutputActivation::Softplus }
    }
}
