//! The scene model: Gaussian centres (mm), bounded scales, rotations, and the opacity field that
//! gives each Gaussian its density — all burn parameters, trained with burn's Adam.

pub mod field;

use burn::module::{Module, Param};
use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_render::Gaussians;

use ctadsa_ops::readback::host_vec;
use ctadsa_ops::scale_op;
use field::{FieldConfig, OpacityField};

/// Scale bounds: `s = (max − min)·sigmoid(raw) + min` (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleBounds {
    pub min_mm: f32,
    pub max_mm: f32,
}

impl ScaleBounds {
    /// The paper's bounds, `[0.1 h, 10 h]` for working-grid voxel `h`, in units of `h`.
    pub fn from_voxel(h_mm: f64, min_voxels: f64, max_voxels: f64) -> Self {
        Self { min_mm: (min_voxels * h_mm) as f32, max_mm: (max_voxels * h_mm) as f32 }
    }

    /// The scale (mm) of raw parameter `raw`, on the host in f32 (the tensor version is
    /// [`GaussianModel::scales`]).
    pub fn scale_mm(&self, raw: f32) -> f32 {
        (self.max_mm - self.min_mm) * (1.0 / (1.0 + (-raw).exp())) + self.min_mm
    }

    /// [`Self::scale_mm`] evaluated in f64.
    pub fn scale_mm_f64(&self, raw: f64) -> f64 {
        (self.max_mm - self.min_mm) as f64 / (1.0 + (-raw).exp()) + self.min_mm as f64
    }

    /// The raw parameter giving scale `s` (clamped inside the bounds).
    pub fn inverse(&self, s: f32) -> f32 {
        let t = ((s - self.min_mm) / (self.max_mm - self.min_mm)).clamp(1e-4, 1.0 - 1e-4);
        (t / (1.0 - t)).ln()
    }
}

/// Host arrays of an initial (or edited) set of Gaussians.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GaussianInit {
    /// `[N·3]` mm.
    pub means: Vec<f32>,
    /// `[N·3]` raw (pre-sigmoid) scales.
    pub raw_scales: Vec<f32>,
    /// `[N·4]` quaternions `(w, x, y, z)`.
    pub rotations: Vec<f32>,
}

impl GaussianInit {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len() / 3
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }
}

/// Gaussians + opacity field.
#[derive(Module, Debug)]
pub struct GaussianModel {
    /// Centres `[N, 3]` (mm).
    pub means: Param<Tensor<2>>,
    /// Pre-activation scales `[N, 3]`.
    pub raw_scales: Param<Tensor<2>>,
    /// Quaternions `[N, 4]` (w, x, y, z), normalised by the renderer.
    pub rotations: Param<Tensor<2>>,
    pub field: OpacityField,
    #[module(skip)]
    pub bounds: ScaleBounds,
}

/// A `[n, cols]` tensor from host data.
pub fn tensor2(data: Vec<f32>, cols: usize, device: &Device) -> Tensor<2> {
    let n = data.len() / cols;
    Tensor::from_data(TensorData::new(data, [n, cols]), device)
}

impl GaussianModel {
    /// A model from initial Gaussians and a fresh field.
    pub fn new(init: &GaussianInit, field: OpacityField, bounds: ScaleBounds, device: &Device) -> Self {
        Self {
            means: Param::from_tensor(tensor2(init.means.clone(), 3, device)),
            raw_scales: Param::from_tensor(tensor2(init.raw_scales.clone(), 3, device)),
            rotations: Param::from_tensor(tensor2(init.rotations.clone(), 4, device)),
            field,
            bounds,
        }
    }

    /// A fresh field for `config` over a box; its random weights come from `seed`.
    pub fn new_field(
        config: &FieldConfig,
        min_mm: [f32; 3],
        size_mm: [f32; 3],
        initial_density: f32,
        seed: u64,
        device: &Device,
    ) -> OpacityField {
        OpacityField::new(config, min_mm, size_mm, initial_density, seed, device)
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.val().dims()[0]
    }

    /// Whether there is no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Scales `[N, 3]` (mm).
    pub fn scales(&self) -> Tensor<2> {
        let b = self.bounds;
        scale_op::bounded_scale(self.raw_scales.val(), b.min_mm, b.max_mm)
    }

    /// Densities `[N]` from the field at the centres.
    pub fn densities(&self) -> Tensor<1> {
        self.field.forward(self.means.val())
    }

    /// The render inputs.
    pub fn gaussians(&self) -> Gaussians {
        Gaussians {
            means: self.means.val(),
            scales: self.scales(),
            rotations: self.rotations.val(),
            densities: self.densities(),
        }
    }

    /// The Gaussian parameters as host arrays.
    pub fn to_init(&self) -> GaussianInit {
        GaussianInit {
            means: host_vec(self.means.val()),
            raw_scales: host_vec(self.raw_scales.val()),
            rotations: host_vec(self.rotations.val()),
        }
    }
}
