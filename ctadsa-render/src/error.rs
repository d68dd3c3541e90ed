//! Errors of the renderer's public API.

/// What can go wrong when setting up or calling the renderer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// A view's geometry is not usable (named problem).
    #[error("invalid view geometry: {0}")]
    InvalidView(String),
    /// The views of one render call do not share a detector size.
    #[error(
        "all views of a render call must have the same size; view {index} is {got:?}, view 0 is {expected:?} (width, height)"
    )]
    MixedViewSizes { index: usize, expected: (u32, u32), got: (u32, u32) },
    /// No view was given.
    #[error("at least one view is needed")]
    NoViews,
    /// An input tensor has the wrong shape.
    #[error("`{name}` must have shape {expected}, got {got:?}")]
    Shape { name: &'static str, expected: String, got: Vec<usize> },
    /// A Gaussian parameter is NaN/infinite, or otherwise unusable.
    #[error("Gaussian {index}: {problem}")]
    InvalidGaussian { index: usize, problem: String },
    /// A setting is out of range.
    #[error("invalid setting: {0}")]
    InvalidSetting(String),
    /// A voxel grid is not usable.
    #[error("invalid voxel grid: {0}")]
    InvalidGrid(String),
    /// Reading a tensor back from the device failed.
    #[error("reading a tensor from the device failed: {0}")]
    Readback(String),
}
