//! The fused Adam update as a burn backend op: one multi-threaded pass on NdArray, one kernel
//! launch per parameter on CubeCL (`gpu.rs`).

#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22 in favour of burn-flex.

use burn::backend::{
    Autodiff, AutodiffBackend, Backend, ExtensionType, NdArray, TensorMetadata, backend_extension, tensor::FloatTensor,
};
use rayon::prelude::*;

use burn::backend::ndarray::NdArrayTensor;
use ndarray::{ArcArray, IxDyn};

use crate::ndarray_host::{host, with_host};

/// Scalars of one Adam step of one parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamCoefficients {
    pub beta_1: f32,
    pub beta_2: f32,
    pub epsilon: f32,
    /// Coupled L2 penalty.
    pub weight_decay: Option<f32>,
    pub lr: f32,
    /// The step number, from 1.
    pub time: i32,
}

impl AdamCoefficients {
    /// burn's `√(1 − β₂ᵗ)` and `√(1 − β₂ᵗ) / (1 − β₁ᵗ)`, in f32 as burn computes them.
    pub(crate) fn bias_corrections(&self) -> (f32, f32) {
        let bc2_sqrt = (1.0 - self.beta_2.powi(self.time)).sqrt();
        (bc2_sqrt, bc2_sqrt / (1.0 - self.beta_1.powi(self.time)))
    }
}

/// The updated parameter and moments.
#[derive(ExtensionType)]
pub struct AdamUpdate<B: Backend> {
    pub param: FloatTensor<B>,
    pub moment_1: FloatTensor<B>,
    pub moment_2: FloatTensor<B>,
}

/// Backend operation of the fused Adam step.
#[backend_extension(Autodiff, Cube: cfg(feature = "wgpu"), NdArray)]
pub trait FusedAdamBackend: Backend {
    /// One Adam step of `param` with `grad` and moments `moment_1`, `moment_2` (all one shape).
    fn adam_update(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        c: AdamCoefficients,
    ) -> AdamUpdate<Self>;
}

/// Elements per parallel task.
const CHUNK: usize = 1 << 15;

/// Below this magnitude an operand is dropped (counted as zero) so that no product of the loop
/// reads or makes a subnormal number (|x| < 1.2e-38): x86 CPUs take a slow path for those, and
/// a long run's table moments decay into that range (the Adam stage went from 11 to 35–59 ms
/// per step after ≈ 400 paper-scale steps).
#[inline(always)]
fn above(x: f32, threshold: f32) -> f32 {
    if x.abs() < threshold { 0.0 } else { x }
}

/// The fused loop, in place on host slices (`param`, `moment_1`, `moment_2` updated). The
/// expression order is burn's, so results agree with burn's Adam to the last bit wherever no
/// term falls below the smallest normal f32 (≈ 1.2e-38), which the loop flushes to zero.
pub fn adam_in_place(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], c: AdamCoefficients) {
    assert!(g.len() == p.len() && m.len() == p.len() && v.len() == p.len(), "Adam operands differ in length");
    let (bc2_sqrt, combined) = c.bias_corrections();
    let eps = c.epsilon * bc2_sqrt;
    let (f1, f2) = (1.0 - c.beta_1, 1.0 - c.beta_2);
    // Operands whose product with the factor would be subnormal.
    let tiny = f32::MIN_POSITIVE;
    let (tiny_m, tiny_v, tiny_g1, tiny_g2) = (tiny / c.beta_1, tiny / c.beta_2, tiny / f1, (tiny / f2).sqrt());
    let tiny_p = c.weight_decay.map_or(0.0, |l| tiny / l);
    let k = LoopConstants { c, combined, eps, f1, f2, tiny, tiny_m, tiny_v, tiny_g1, tiny_g2, tiny_p };
    p.par_chunks_mut(CHUNK)
        .zip(g.par_chunks(CHUNK))
        .zip(m.par_chunks_mut(CHUNK))
        .zip(v.par_chunks_mut(CHUNK))
        .with_max_len(1)
        .for_each(|(((p, g), m), v)| match c.weight_decay {
            Some(l) => adam_chunk::<true>(p, g, m, v, &k, l),
            None => adam_chunk::<false>(p, g, m, v, &k, 0.0),
        });
}

/// The scalars of [`adam_in_place`]'s loop.
struct LoopConstants {
    c: AdamCoefficients,
    combined: f32,
    eps: f32,
    f1: f32,
    f2: f32,
    tiny: f32,
    tiny_m: f32,
    tiny_v: f32,
    tiny_g1: f32,
    tiny_g2: f32,
    tiny_p: f32,
}

/// One chunk of [`adam_in_place`] (compiled for AVX2 where the CPU has it: the flushes become
/// blends of eight lanes). `DECAY`: whether the coupled L2 term `l · p` is added.
#[multiversion::multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn adam_chunk<const DECAY: bool>(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], k: &LoopConstants, l: f32) {
    let c = &k.c;
    let n = p.len().min(g.len()).min(m.len()).min(v.len());
    let (p, g, m, v) = (&mut p[..n], &g[..n], &mut m[..n], &mut v[..n]);
    for i in 0..n {
        let gi = if DECAY { above(p[i], k.tiny_p) * l + above(g[i], k.tiny) } else { above(g[i], k.tiny) };
        let mi = above(m[i], k.tiny_m) * c.beta_1 + above(gi, k.tiny_g1) * k.f1;
        let g2 = above(gi, k.tiny_g2);
        let vi = above(v[i], k.tiny_v) * c.beta_2 + g2 * g2 * k.f2;
        let step = mi * k.combined / (vi.sqrt() + k.eps);
        p[i] -= step * c.lr;
        m[i] = mi;
        v[i] = vi;
    }
}

/// The values of an NdArray tensor as an owned contiguous f32 array: the tensor's own buffer
/// when it is uniquely owned f32 (the usual case for parameters and moments after backward), a
/// copy otherwise.
fn owned_f32(t: FloatTensor<NdArray>) -> ArcArray<f32, IxDyn> {
    let mut array = match t {
        NdArrayTensor::F32(storage) => storage.into_owned(),
        other => {
            let shape = other.shape();
            ArcArray::from_shape_vec(IxDyn(&shape), host::<NdArray>(other)).expect("shape matches the values")
        }
    };
    if array.as_slice_mut().is_none() {
        array = array.as_standard_layout().to_owned().into_shared();
    }
    array
}

impl FusedAdamBackend for NdArray {
    fn adam_update(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        c: AdamCoefficients,
    ) -> AdamUpdate<Self> {
        let (mut p, mut m, mut v) = (owned_f32(param), owned_f32(moment_1), owned_f32(moment_2));
        with_host(&grad, |g| {
            let (ps, ms, vs) = (p.as_slice_mut(), m.as_slice_mut(), v.as_slice_mut());
            adam_in_place(
                ps.expect("standard layout"),
                g,
                ms.expect("standard layout"),
                vs.expect("standard layout"),
                c,
            )
        });
        let tensor = |a: ArcArray<f32, IxDyn>| NdArrayTensor::F32(a.into());
        AdamUpdate { param: tensor(p), moment_1: tensor(m), moment_2: tensor(v) }
    }
}

impl<B: Backend + FusedAdamBackend, C: burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy>
    FusedAdamBackend for Autodiff<B, C>
{
    fn adam_update(
        param: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        moment_1: FloatTensor<Self>,
        moment_2: FloatTensor<Self>,
        c: AdamCoefficients,
    ) -> AdamUpdate<Self> {
        let out = B::adam_update(
            param.into_primitive(),
            grad.into_primitive(),
            moment_1.into_primitive(),
            moment_2.into_primitive(),
            c,
        );
        AdamUpdate {
            param: Self::from_inner(out.param),
            moment_1: Self::from_inner(out.moment_1),
            moment_2: Self::from_inner(out.moment_2),
        }
    }
}
