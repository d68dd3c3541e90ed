//! The encoding's settings and hash: what the kernels index by, owned by the op.

use ctadsa_render::F32Add;
use serde::{Deserialize, Serialize};

/// Hash multipliers, below 2¹⁹ so that `coordinate × P` fits in i32 for resolutions < 2¹².
pub const HASH_P1: i64 = 265_443;
pub const HASH_P2: i64 = 433_879;

/// Settings of the encoding (paper: 16 levels, 2 features, T = 2¹⁹, base 8, growth 1.45).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HashGridConfig {
    pub levels: usize,
    pub features: usize,
    /// `log₂ T`, the per-level table size.
    pub log2_table: u32,
    pub base_resolution: f64,
    pub growth: f64,
    /// How the GPU backward adds the table gradient atomically (not a TOML setting).
    #[serde(skip)]
    pub f32_add: F32Add,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        Self { levels: 16, features: 2, log2_table: 19, base_resolution: 8.0, growth: 1.45, f32_add: F32Add::Auto }
    }
}

impl HashGridConfig {
    /// Checks the ranges (resolution below 2¹² so that the hash stays in i32).
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=32).contains(&self.levels) {
            return Err(format!("field.levels must be in 1..=32, got {}", self.levels));
        }
        if !(1..=8).contains(&self.features) {
            return Err(format!("field.features must be in 1..=8, got {}", self.features));
        }
        if !(4..=24).contains(&self.log2_table) {
            return Err(format!("field.log2_table must be in 4..=24, got {}", self.log2_table));
        }
        if !(self.base_resolution >= 1.0 && self.growth >= 1.0) {
            return Err("field.base_resolution and field.growth must be ≥ 1".into());
        }
        let finest = self.resolution(self.levels - 1);
        if finest >= 4096 {
            return Err(format!("the finest level has resolution {finest}; it must stay below 4096"));
        }
        Ok(())
    }

    /// Cells per unit of level `l`.
    pub fn resolution(&self, l: usize) -> i64 {
        (self.base_resolution * self.growth.powi(l as i32)).floor() as i64
    }

    /// Table rows per level.
    pub fn table_size(&self) -> i64 {
        1i64 << self.log2_table
    }

    /// Whether level `l` is stored densely.
    pub fn dense(&self, l: usize) -> bool {
        (self.resolution(l) + 1).pow(3) <= self.table_size()
    }

    /// Rows of level `l`: `(r + 1)³` when dense, `T` when hashed.
    pub fn level_rows(&self, l: usize) -> usize {
        if self.dense(l) { (self.resolution(l) + 1).pow(3) as usize } else { self.table_size() as usize }
    }

    /// First row of level `l` in the parameter.
    pub fn level_offset(&self, l: usize) -> usize {
        (0..l).map(|j| self.level_rows(j)).sum()
    }

    /// Rows of the parameter, all levels: `R`.
    pub fn rows(&self) -> usize {
        self.level_offset(self.levels)
    }

    /// Rows of the layout that padded every level to `T` rows (`levels · T`), that of
    /// checkpoints before the compact layout.
    pub fn padded_rows(&self) -> usize {
        self.levels * self.table_size() as usize
    }

    /// The parameter row (in `0..R`) of each row of the layout with every level padded to `T`
    /// rows (`levels · T`, that of checkpoints before the compact layout), or `None` for the
    /// padding.
    pub fn compact_row(&self, padded_row: usize) -> Option<usize> {
        let t = self.table_size() as usize;
        let (l, r) = (padded_row / t, padded_row % t);
        (l < self.levels && r < self.level_rows(l)).then(|| self.level_offset(l) + r)
    }

    /// Compacts a `[features, levels · T]` row-major table (the padded layout) to `[features, R]`.
    pub fn compact_table(&self, padded: &[f32]) -> Vec<f32> {
        let t = self.table_size() as usize;
        let padded_rows = self.padded_rows();
        let mut out = Vec::with_capacity(self.features * self.rows());
        for feature in padded.chunks_exact(padded_rows).take(self.features) {
            for (l, level) in feature.chunks_exact(t).enumerate() {
                out.extend_from_slice(&level[..self.level_rows(l)]);
            }
        }
        out.resize(self.features * self.rows(), 0.0);
        out
    }

    /// Output width `levels × features`.
    pub fn output_dim(&self) -> usize {
        self.levels * self.features
    }
}
