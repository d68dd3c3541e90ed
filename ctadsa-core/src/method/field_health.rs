//! Whether the opacity field still tells the Gaussians apart. The field starts constant (its hash
//! table starts near zero) and training spreads its densities over decades; a trained field whose
//! densities are all the same has collapsed: the model is then Gaussians of one shared density,
//! and density pruning can never fire. With Adam, a coupled weight decay on the field does this
//! once the image gradients have become small (`optim.field_weight_decay`, docs/RESULTS.md).

use serde::Serialize;

/// Percentiles of the field's densities at the Gaussians' centres (density units, per mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DensitySpread {
    pub p1: f32,
    pub p50: f32,
    pub p99: f32,
}

impl DensitySpread {
    /// Relative spread (`(p99 − p1) / p50`) below which the field counts as constant. A
    /// collapsed field agrees to the last digit (spread ≈ 1e-7); one that is learning spreads
    /// beyond 1e-3 within tens of steps.
    pub const CONSTANT_BELOW: f32 = 1e-4;

    /// The percentiles of `densities`; `None` when there are none or any is not finite.
    pub fn of(densities: &[f32]) -> Option<Self> {
        if densities.is_empty() || densities.iter().any(|d| !d.is_finite()) {
            return None;
        }
        let mut sorted = densities.to_vec();
        sorted.sort_by(f32::total_cmp);
        let at = |q: f64| sorted[(q * (sorted.len() - 1) as f64).round() as usize];
        Some(Self { p1: at(0.01), p50: at(0.5), p99: at(0.99) })
    }

    /// Whether the field gives (almost) every Gaussian the same density.
    pub fn is_constant(&self) -> bool {
        self.p99 - self.p1 <= Self::CONSTANT_BELOW * self.p50.abs().max(f32::MIN_POSITIVE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_single_density_is_constant_and_a_spread_is_not() {
        let constant = DensitySpread::of(&[0.098; 1000]).unwrap();
        assert!(constant.is_constant());
        assert_eq!((constant.p1, constant.p50, constant.p99), (0.098, 0.098, 0.098));
        // The paper configuration's field 20 steps in: a spread of 0.1 % is a field that learns.
        let learning: Vec<f32> = (0..1000).map(|i| 0.025235 + 0.026e-3 * i as f32 / 999.0).collect();
        assert!(!DensitySpread::of(&learning).unwrap().is_constant());
        let spread: Vec<f32> = (0..1000).map(|i| 1e-6 * 10f32.powf(i as f32 / 200.0)).collect();
        let s = DensitySpread::of(&spread).unwrap();
        assert!(!s.is_constant() && s.p1 < s.p50 && s.p50 < s.p99);
        assert_eq!(DensitySpread::of(&[]), None);
        assert_eq!(DensitySpread::of(&[1.0, f32::NAN]), None);
    }
}
