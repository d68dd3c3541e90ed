//! Helpers shared by the renderer's integration tests.
#![allow(dead_code)]
#![allow(deprecated)] // burn-ndarray is deprecated in burn 0.22; it is the CPU backend the tests use.

use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_render::reference::RefGaussian;
use ctadsa_render::{ConeBeamView, Gaussians, TigreGeometry, ViewSet};

/// A small deterministic generator (SplitMix64), so tests do not depend on a rand version.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random anisotropic, rotated Gaussians near the isocentre.
pub fn random_gaussians(rng: &mut Rng, n: usize, spread_mm: f64, scale_range: (f64, f64)) -> Vec<RefGaussian> {
    (0..n)
        .map(|_| RefGaussian {
            mean: [0; 3].map(|_| rng.uniform(-spread_mm, spread_mm)),
            scale: [0; 3].map(|_| rng.uniform(scale_range.0, scale_range.1)),
            quat: [0; 4].map(|_| rng.uniform(-1.0, 1.0)),
            density: rng.uniform(0.2, 1.5),
        })
        .collect()
}

/// The Gaussians as tensors on `device`.
pub fn to_tensors(gs: &[RefGaussian], device: &Device) -> Gaussians {
    let n = gs.len();
    let flat = |f: &dyn Fn(&RefGaussian) -> Vec<f64>| -> Vec<f32> { gs.iter().flat_map(f).map(|v| v as f32).collect() };
    Gaussians {
        means: Tensor::from_data(TensorData::new(flat(&|g| g.mean.to_vec()), [n, 3]), device),
        scales: Tensor::from_data(TensorData::new(flat(&|g| g.scale.to_vec()), [n, 3]), device),
        rotations: Tensor::from_data(TensorData::new(flat(&|g| g.quat.to_vec()), [n, 4]), device),
        densities: Tensor::from_data(TensorData::new(flat(&|g| vec![g.density]), [n]), device),
    }
}

/// A small TIGRE-style detector (keeps tests fast): `size` px of `pitch` mm, DSD 700, DSO 500.
pub fn small_geometry(primary_deg: f64, size: u32, pitch_mm: f64) -> TigreGeometry {
    TigreGeometry {
        dsd_mm: 700.0,
        dso_mm: 500.0,
        detector_px: [size, size],
        pixel_mm: [pitch_mm, pitch_mm],
        offset_mm: [0.0, 0.0],
        primary_deg,
        secondary_deg: 0.0,
    }
}

pub fn view_set(geoms: &[TigreGeometry]) -> ViewSet {
    ViewSet::new(geoms.iter().map(|g| ConeBeamView::from_tigre(g).unwrap()).collect()).unwrap()
}

pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().to_vec::<f32>().expect("f32 data")
}

/// ‖a − b‖₂ / ‖b‖₂.
pub fn rel_l2(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}
