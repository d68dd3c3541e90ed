//! The settings of a render call.

use crate::RenderError;

/// How the GPU kernels add f32 sums into an image or volume atomically (the CPU kernels add
/// without atomics and ignore it). Both give the same sums up to the order of float rounding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum F32Add {
    /// The device's own f32 atomic add where it has one (Vulkan's
    /// `shaderBufferFloat32AtomicAdd`: NVIDIA, AMD, Mesa lavapipe), else the loop.
    #[default]
    Auto,
    /// A compare-and-swap loop on the f32's bits: needs only 32-bit integer atomics. Slower
    /// where many threads add to one address (they retry).
    CompareExchange,
}

/// Settings of a render call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderSettings {
    /// Footprint cut-off `k` in standard deviations (default 3): a ray farther than `k`
    /// Mahalanobis units from a Gaussian's centre does not see it (the neglected tail is at most
    /// `e^{−k²/2}` of that ray's peak, 1.1% for k = 3). Must be in `(0, 20]`.
    pub k_sigma: f32,
    /// How the GPU kernels add atomically (default: the device's best).
    pub f32_add: F32Add,
    /// Units per Gaussian (and view) in the GPU render kernels, each walking every `row_split`-th
    /// row of the footprint: 0 (default) picks by the detector's height (one per 64 rows, at most
    /// 8), else a power of two ≤ 64. The CPU kernels ignore it; results agree up to the order
    /// of float rounding.
    pub row_split: u32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { k_sigma: 3.0, f32_add: F32Add::Auto, row_split: 0 }
    }
}

impl RenderSettings {
    pub(crate) fn validate(&self) -> Result<(), RenderError> {
        if !(self.k_sigma > 0.0 && self.k_sigma <= 20.0) {
            return Err(RenderError::InvalidSetting(format!("k_sigma must be in (0, 20], got {}", self.k_sigma)));
        }
        if !(self.row_split == 0 || (self.row_split.is_power_of_two() && self.row_split <= MAX_ROW_SPLIT)) {
            return Err(RenderError::InvalidSetting(format!(
                "row_split must be 0 (by the detector's height) or a power of two ≤ {MAX_ROW_SPLIT}, got {}",
                self.row_split
            )));
        }
        Ok(())
    }

    /// The render kernels' units per Gaussian for views `height_px` high ([`Self::row_split`]).
    pub fn row_split_for(&self, height_px: u32) -> u32 {
        if self.row_split > 0 { self.row_split } else { (height_px / 64).clamp(1, 8).next_power_of_two() }
    }
}

/// Largest [`RenderSettings::row_split`] (the GPU kernels' workgroup size).
pub const MAX_ROW_SPLIT: u32 = 64;
