//! The TOML configuration of a completion run. Every section and key has a default (the
//! paper's values where the paper gives one); unknown keys and out-of-range values are errors
//! that name the key. `--set section.key=value` overrides are applied to the TOML tree before
//! it is read, so they are checked the same way.

mod densify;
mod init;
mod load;
mod loss;
mod members;
mod model;
mod optim;
mod output;
mod pose;
mod run;
mod validate;

use serde::{Deserialize, Serialize};

use crate::error::Result;

pub use ctadsa_ops::hash_grid::HashGridConfig;
pub use densify::DensifyConfig;
pub use init::{InitConfig, SeedMode};
pub use loss::LossConfig;
pub use model::{FieldConfig, ModelConfig, OutputActivation};
pub use optim::{AdamImpl, LrRange, OptimConfig};
pub use output::OutputConfig;
pub use pose::PoseConfig;
pub use run::{RunConfig, WorkingBoxSource};

/// The most further image-seeded members a config may ask for (`run.member_seeds`).
pub const MAX_MEMBER_SEEDS: usize = 8;

/// The most Gaussians (or seeds, or samples) a config may ask for: far beyond the paper's
/// 500,000 cap, and small enough to fail with a message rather than an allocation abort.
pub const MAX_GAUSSIANS: usize = 20_000_000;

/// Largest number of metric samples per surface (`output.metric_samples`, `ctadsa eval
/// --samples`): a larger request is an error, not an allocation.
pub const MAX_SAMPLES: usize = 10_000_000;

/// The widest dilation (pixels) of a projected prior or residual mask a config may ask for.
pub const MAX_DILATION_PX: u32 = 64;

/// The widest field MLP a config may ask for.
pub const MAX_HIDDEN: usize = 4096;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    pub run: RunConfig,
    pub init: InitConfig,
    pub model: ModelConfig,
    pub field: FieldConfig,
    pub optim: OptimConfig,
    pub loss: LossConfig,
    pub densify: DensifyConfig,
    pub output: OutputConfig,
    pub pose: PoseConfig,
}

/// `configs/quick.toml`, built in (the demo's and the benchmarks' configuration).
pub const QUICK_TOML: &str = include_str!("../../../configs/quick.toml");

/// `configs/baselines/paper-method.toml` (the paper's method and schedule), built in: the
/// workload of the paper rows of `ctadsa bench`.
pub const PAPER_METHOD_TOML: &str = include_str!("../../../configs/baselines/paper-method.toml");

impl Config {
    /// The built-in quick configuration ([`QUICK_TOML`]) with `key=value` overrides.
    pub fn quick(overrides: &[String]) -> Result<Self> {
        Self::from_toml_str(QUICK_TOML, "configs/quick.toml", overrides)
    }

    /// The built-in paper-method baseline ([`PAPER_METHOD_TOML`]) with `key=value` overrides.
    pub fn paper_method(overrides: &[String]) -> Result<Self> {
        Self::from_toml_str(PAPER_METHOD_TOML, "configs/baselines/paper-method.toml", overrides)
    }

    /// The configuration as TOML (written next to every run).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests;
