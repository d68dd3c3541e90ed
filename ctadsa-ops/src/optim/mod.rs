//! Adam as one fused pass per parameter: the same update rule as burn's `Adam` (coupled L2
//! weight decay, bias corrections in burn's `ε·√(1 − β₂ᵗ)` form), the same state record as
//! burn's `AdamState` ([`FusedAdamState`], so checkpoints and densification's state edits are
//! unchanged), but each step
//! reads the parameter, gradient and moments once and writes them once instead of making about
//! fifteen full-size tensor passes. burn's `Adam` stays the reference (`optim.adam = "burn"`)
//! and the test oracle.

#[cfg(feature = "wgpu")]
mod gpu;
mod kernel;
mod state;
pub mod state_edit;

use burn::backend::Dispatch;
use burn::optim::{LearningRate, Optimizer};
use burn::tensor::{Device, Tensor};

pub use kernel::{AdamCoefficients, FusedAdamBackend};
pub use state::FusedAdamState;

/// Adam with one fused pass per parameter tensor (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FusedAdam {
    pub beta_1: f32,
    pub beta_2: f32,
    pub epsilon: f32,
    /// Coupled L2 penalty (added to the gradient as `penalty · parameter`), as burn's
    /// `WeightDecayConfig`.
    pub weight_decay: Option<f32>,
}

impl FusedAdam {
    /// burn's defaults for the betas; `epsilon` as given.
    pub fn new(epsilon: f32) -> Self {
        Self { beta_1: 0.9, beta_2: 0.999, epsilon, weight_decay: None }
    }

    /// With a coupled L2 penalty.
    pub fn with_weight_decay(mut self, penalty: Option<f32>) -> Self {
        self.weight_decay = penalty;
        self
    }
}

impl Optimizer for FusedAdam {
    type State<const D: usize> = FusedAdamState<D>;

    fn step<const D: usize>(
        &self,
        lr: LearningRate,
        tensor: Tensor<D>,
        grad: Tensor<D>,
        state: Option<Self::State<D>>,
    ) -> (Tensor<D>, Option<Self::State<D>>) {
        // No state yet: zero moments give burn's first-step values exactly (0·β + x = x).
        let (time, moment_1, moment_2) = match state {
            Some(s) => (s.time + 1, s.moment_1, s.moment_2),
            None => (1, grad.zeros_like(), grad.zeros_like()),
        };
        let coefficients = AdamCoefficients {
            beta_1: self.beta_1,
            beta_2: self.beta_2,
            epsilon: self.epsilon,
            weight_decay: self.weight_decay,
            lr: lr as f32,
            time: time as i32,
        };
        let out = <Dispatch as FusedAdamBackend>::adam_update(
            tensor.into_dispatch(),
            grad.into_dispatch(),
            moment_1.into_dispatch(),
            moment_2.into_dispatch(),
            coefficients,
        );
        let state = FusedAdamState {
            time,
            moment_1: Tensor::from_dispatch(out.moment_1),
            moment_2: Tensor::from_dispatch(out.moment_2),
        };
        (Tensor::from_dispatch(out.param), Some(state))
    }

    fn to_device<const D: usize>(state: Self::State<D>, device: &Device) -> Self::State<D> {
        FusedAdamState {
            time: state.time,
            moment_1: state.moment_1.to_device(device),
            moment_2: state.moment_2.to_device(device),
        }
    }
}

#[cfg(test)]
mod tests;
