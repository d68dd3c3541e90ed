//! A set of views rendered together.

use std::sync::Arc;

use crate::{ConeBeamView, RenderError, RenderSettings, RenderSetup, ViewParams};

/// A set of views rendered together; all have the same detector size.
#[derive(Debug, Clone)]
pub struct ViewSet {
    views: Arc<[ConeBeamView]>,
    packed: Arc<[ViewParams]>,
}

impl ViewSet {
    /// Checks that there is at least one view and that all have the same size.
    pub fn new(views: Vec<ConeBeamView>) -> Result<Self, RenderError> {
        let first = views.first().ok_or(RenderError::NoViews)?;
        let expected = (first.width(), first.height());
        for (index, v) in views.iter().enumerate() {
            let got = (v.width(), v.height());
            if got != expected {
                return Err(RenderError::MixedViewSizes { index, expected, got });
            }
        }
        let packed = views.iter().map(ViewParams::new).collect();
        Ok(Self { views: views.into(), packed })
    }

    /// The views.
    pub fn views(&self) -> &[ConeBeamView] {
        &self.views
    }

    /// Number of views `V`.
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// Always false (a view set has at least one view).
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// `(width, height)` of every view, in pixels.
    pub fn image_size(&self) -> (u32, u32) {
        (self.views[0].width(), self.views[0].height())
    }

    /// The views packed as f32 for the kernels.
    pub fn packed(&self) -> &[ViewParams] {
        &self.packed
    }

    /// The subset of views with the given indices (in that order).
    pub fn select(&self, indices: &[usize]) -> Result<Self, RenderError> {
        let views = indices
            .iter()
            .map(|&i| {
                self.views.get(i).copied().ok_or_else(|| {
                    RenderError::InvalidSetting(format!("view index {i} out of range (have {})", self.len()))
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Self::new(views)
    }

    pub(crate) fn setup(&self, settings: &RenderSettings) -> RenderSetup {
        RenderSetup {
            views: self.packed.clone(),
            k_sigma: settings.k_sigma,
            f32_add: settings.f32_add,
            row_split: settings.row_split_for(self.packed.first().map_or(0, |v| v.height)),
        }
    }
}
