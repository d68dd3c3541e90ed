//! Reproducible random initial values, drawn on the host (burn's own generator is global and
//! shared by every thread, so it cannot make runs reproducible).

use burn::tensor::{Device, Tensor, TensorData};

/// A `shape` tensor of values uniform in `±bound`, drawn from `seed` on the host (burn's own
/// generator is global and shared by every thread, so it cannot make runs reproducible).
pub fn uniform_tensor(shape: [usize; 2], bound: f64, seed: u64, device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(uniform_values(shape[0] * shape[1], bound, seed), shape), device)
}

/// `count` values uniform in `±bound` from `seed` (the values of [`uniform_tensor`]).
pub fn uniform_values(count: usize, bound: f64, seed: u64) -> Vec<f32> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..count).map(|_| rng.random_range(-bound..=bound) as f32).collect()
}
