//! [`FusedAdam`](super::FusedAdam)'s per-parameter state. Its record is burn's `AdamState`'s,
//! leaf for leaf (`momentum.time`, `momentum.moment_1`, `momentum.moment_2`), so checkpoints and
//! densification's state edits read and write either; only the reading differs: burn's derived
//! record copies each moment out of a shared burn-ndarray array element by element (≈ 95 ms of a
//! 126 ms densification call at 180k Gaussians), this one makes one unshared copy and hands its
//! buffer over.

use burn::optim::{RecordState, StateSink, StateSource, join_path};
use burn::tensor::{Device, Tensor, TensorData};
use burn_pack::Scalar;

use crate::readback::host_vec;

/// Adam's moments of one parameter and the number of steps taken.
#[derive(Clone)]
pub struct FusedAdamState<const D: usize> {
    /// Steps taken (burn's `momentum.time`).
    pub time: usize,
    /// First moment, the parameter's shape.
    pub moment_1: Tensor<D>,
    /// Second moment, the parameter's shape.
    pub moment_2: Tensor<D>,
}

/// burn's `AdamState` nests its fields under this name.
const MOMENTUM: &str = "momentum";

/// `t`'s values through [`host_vec`] (an unshared copy whose buffer burn-ndarray gives away
/// without its element-by-element fallback for shared arrays), with `t`'s shape.
fn host_data<const D: usize>(t: &Tensor<D>) -> TensorData {
    TensorData::new(host_vec(t.clone()), t.shape())
}

impl<const D: usize> RecordState for FusedAdamState<D> {
    fn state_flatten(&self, prefix: &str, out: &mut StateSink) {
        let path = join_path(prefix, MOMENTUM);
        out.push_scalar(&path, "time", Scalar::from(self.time));
        out.push_tensor(&path, "moment_1", host_data(&self.moment_1));
        out.push_tensor(&path, "moment_2", host_data(&self.moment_2));
    }

    fn state_unflatten(prefix: &str, src: &mut StateSource, device: &Device) -> Option<Self> {
        let path = join_path(prefix, MOMENTUM);
        let time = usize::try_from(src.take_scalar(&path, "time")?).ok()?;
        let moment_1 = Tensor::from_data(src.take_tensor(&path, "moment_1")?, device);
        let moment_2 = Tensor::from_data(src.take_tensor(&path, "moment_2")?, device);
        Some(Self { time, moment_1, moment_2 })
    }
}
