//! Optional noise on synthesised DSA line integrals.
//!
//! - Poisson (quantum) noise: a pixel with line integral `p` (value × mm) is seen through
//!   `n ~ Poisson(I₀ exp(−μ p))` photons and reconstructed as `p̂ = −ln(max(n, 1)/I₀)/μ`;
//!   `μ` converts line-integral units into attenuation (1 / value / mm).
//! - Gaussian (electronic) noise: `p̂ += N(0, σ²)`.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Noise settings; all off by default.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseModel {
    /// Unattenuated photons per pixel `I₀` (Poisson noise when set).
    pub poisson_photons: Option<f64>,
    /// Attenuation per line-integral unit `μ` for the Poisson model (default 1).
    pub attenuation: Option<f64>,
    /// Standard deviation of additive Gaussian noise (line-integral units).
    pub gaussian_sigma: Option<f64>,
    /// Seed of the noise.
    pub seed: u64,
}

/// A standard normal draw (Box–Muller).
pub(crate) fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::MIN_POSITIVE..1.0);
    let u2: f64 = rng.random();
    (-2.0f64 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

fn poisson(rng: &mut ChaCha8Rng, lambda: f64) -> f64 {
    if lambda > 64.0 {
        (lambda + lambda.sqrt() * standard_normal(rng)).round().max(0.0)
    } else {
        let limit = (-lambda).exp();
        let mut k = 0.0;
        let mut p = 1.0;
        loop {
            p *= rng.random::<f64>();
            if p <= limit {
                return k;
            }
            k += 1.0;
        }
    }
}

impl NoiseModel {
    /// Whether any noise is configured.
    pub fn is_active(&self) -> bool {
        self.poisson_photons.is_some() || self.gaussian_sigma.is_some()
    }

    /// Adds the configured noise to `image` (in place); `stream` decorrelates views.
    pub fn apply(&self, image: &mut [f32], stream: u64) {
        if !self.is_active() {
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let mu = self.attenuation.unwrap_or(1.0);
        for px in image.iter_mut() {
            let mut p = *px as f64;
            if let Some(i0) = self.poisson_photons {
                let n = poisson(&mut rng, i0 * (-mu * p).exp());
                p = -(n.max(1.0) / i0).ln() / mu;
            }
            if let Some(sigma) = self.gaussian_sigma {
                p += sigma * standard_normal(&mut rng);
            }
            *px = p as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poisson_noise_is_unbiased_with_the_expected_spread() {
        let model = NoiseModel { poisson_photons: Some(1e4), attenuation: Some(0.1), ..Default::default() };
        let mut img = vec![5.0f32; 50_000];
        model.apply(&mut img, 0);
        let mean = img.iter().map(|&v| v as f64).sum::<f64>() / img.len() as f64;
        let var = img.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / img.len() as f64;
        // Var(p̂) ≈ 1 / (μ² I₀ e^{−μp}).
        let expected = 1.0 / (0.01 * 1e4 * (-0.5f64).exp());
        assert!((mean - 5.0).abs() < 0.01, "{mean}");
        assert!((var / expected - 1.0).abs() < 0.05, "{var} vs {expected}");
    }
}
