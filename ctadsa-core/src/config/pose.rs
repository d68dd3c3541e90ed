//! `[pose]`: per-view pose refinement.

use serde::{Deserialize, Serialize};

/// `[pose]`: refinement of each view's pose (a small rigid correction, 6 parameters per view)
/// jointly with the Gaussians, to absorb registration error. Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PoseConfig {
    pub enabled: bool,
    /// First iteration at which the poses move (the Gaussians settle first).
    pub start: usize,
    /// Adam learning rate of the rotation corrections (rad), decaying from the first to the
    /// second value over the run.
    pub lr_rotation_rad: [f64; 2],
    /// Adam learning rate of the translation corrections (mm).
    pub lr_translation_mm: [f64; 2],
    /// Keep the first view fixed (the reference frame); otherwise the prior alone holds the
    /// global frame.
    pub fix_first_view: bool,
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            start: 0,
            lr_rotation_rad: [5e-4, 5e-5],
            lr_translation_mm: [0.05, 0.005],
            fix_first_view: true,
        }
    }
}
