//! Host access to burn-ndarray tensors without copies where possible, for CPU kernels of
//! backend ops (this crate's renderer, and ops of crates built on it).

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

use burn::backend::{Backend, NdArray, read_sync, tensor::FloatTensor};

/// A tensor's values as an f32 vector (a copy).
pub fn host<B: Backend>(t: FloatTensor<B>) -> Vec<f32> {
    read_sync(B::float_into_data(t))
        .expect("reading a CPU tensor cannot fail")
        .convert::<f32>()
        .to_vec::<f32>()
        .expect("converted to f32")
}

/// Runs `f` on the values of an NdArray tensor: borrowed in place when it is contiguous f32 (no
/// copy — a parameter shared with autodiff and the optimizer would otherwise be copied element
/// by element by `into_data`), copied otherwise.
pub fn with_host<R>(t: &FloatTensor<NdArray>, f: impl FnOnce(&[f32]) -> R) -> R {
    if let burn::backend::ndarray::NdArrayTensor::F32(storage) = t
        && let Some(values) = storage.view().as_slice()
    {
        return f(values);
    }
    f(&host::<NdArray>(t.clone()))
}
