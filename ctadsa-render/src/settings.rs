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
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self { k_sigma: 3.0, f32_add: F32Add::Auto }
    }
}

impl RenderSettings {
    pub(crate) fn validate(&self) -> Result<(), RenderError> {
        if !(self.k_sigma > 0.0 && self.k_sigma <= 20.0) {
            return Err(RenderError::InvalidSetting(format!("k_sigma must be in (0, 20], got {}", self.k_sigma)));
        }
        Ok(())
    }
}
