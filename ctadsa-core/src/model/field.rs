//! The opacity field: hash encoding of the normalised position, then an MLP
//! (hidden ReLU layers, non-negative output) giving each Gaussian's central density.

use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::activation::{relu, softplus};
use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

use super::hash_grid::{HashGrid, HashGridConfig};

/// The MLP's output non-linearity (both non-negative).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OutputActivation {
    /// `max(0, x)`, as the reference implementation (can start or get stuck at zero).
    Relu,
    /// `ln(1 + eˣ)`: strictly positive, never stuck.
    Softplus,
}

/// Field settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FieldConfig {
    pub encoding: HashGridConfig,
    /// Width of the hidden layers.
    pub hidden: usize,
    /// Number of hidden layers (1–4).
    pub hidden_layers: usize,
    pub output: OutputActivation,
}

impl Default for FieldConfig {
    fn default() -> Self {
        Self { encoding: HashGridConfig::default(), hidden: 64, hidden_layers: 2, output: OutputActivation::Softplus }
    }
}

/// Fixed data of a field (not trained).
#[derive(Debug, Clone, Copy)]
pub struct FieldFrame {
    /// The box the encoding spans (mm): `u = (x − min) / size`.
    pub min_mm: [f32; 3],
    pub size_mm: [f32; 3],
    pub output: OutputActivation,
}

/// Hash grid + MLP.
#[derive(Module, Debug)]
pub struct OpacityField {
    pub grid: HashGrid,
    pub hidden: Vec<Linear>,
    pub output: Linear,
    #[module(skip)]
    pub frame: FieldFrame,
}

impl OpacityField {
    /// A new field over the box `[min_mm, min_mm + size_mm]`; the output bias starts at
    /// `initial_density` (through the inverse of the output activation).
    pub fn new(
        config: &FieldConfig,
        min_mm: [f32; 3],
        size_mm: [f32; 3],
        initial_density: f32,
        device: &Device,
    ) -> Self {
        let grid = HashGrid::new(config.encoding, device);
        let mut hidden = Vec::new();
        let mut width = config.encoding.output_dim();
        for _ in 0..config.hidden_layers {
            hidden.push(LinearConfig::new(width, config.hidden).init(device));
            width = config.hidden;
        }
        let mut output = LinearConfig::new(width, 1).init(device);
        let bias = match config.output {
            OutputActivation::Relu => initial_density,
            OutputActivation::Softplus => {
                let d = initial_density.max(1e-6) as f64;
                (d.exp_m1().max(1e-30)).ln() as f32
            }
        };
        output.weight = output.weight.map(|w| w.mul_scalar(0.1).detach().require_grad());
        output.bias =
            Some(burn::module::Param::from_tensor(Tensor::from_data(TensorData::new(vec![bias], [1]), device)));
        Self { grid, hidden, output, frame: FieldFrame { min_mm, size_mm, output: config.output } }
    }

    /// Densities `[N]` at positions `[N, 3]` (mm).
    pub fn forward(&self, positions_mm: Tensor<2>) -> Tensor<1> {
        let n = positions_mm.dims()[0];
        let device = positions_mm.device();
        let min = Tensor::<1>::from_data(TensorData::new(self.frame.min_mm.to_vec(), [3]), &device).reshape([1, 3]);
        let inv = Tensor::<1>::from_data(TensorData::new(self.frame.size_mm.map(|s| 1.0 / s).to_vec(), [3]), &device)
            .reshape([1, 3]);
        let u = (positions_mm - min) * inv;
        let mut x = self.grid.forward(u);
        for layer in &self.hidden {
            x = relu(layer.forward(x));
        }
        let y = self.output.forward(x).reshape([n]);
        match self.frame.output {
            OutputActivation::Relu => relu(y),
            OutputActivation::Softplus => softplus(y, 1.0),
        }
    }
}
