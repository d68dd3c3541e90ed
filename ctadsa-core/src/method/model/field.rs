//! The opacity field: hash encoding of the normalised position, then an MLP
//! (hidden ReLU layers, non-negative output) giving each Gaussian's central density.

use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::tensor::{Device, Tensor, TensorData};

use burn::module::Param;
use ctadsa_ops::field_op::{FieldSpec, Layer, field_densities};
use ctadsa_ops::hash_grid::HashGrid;
use ctadsa_ops::linear_op::Activation;
use ctadsa_ops::random::uniform_tensor;

pub use crate::config::{FieldConfig, OutputActivation};

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
    /// `initial_density` (through the inverse of the output activation). Random weights come
    /// from `seed`: the hash tables uniform in ±1e-4, the linear layers uniform in
    /// ±1/√fan_in (burn's default Kaiming-uniform bound), drawn on the host.
    pub fn new(
        config: &FieldConfig,
        min_mm: [f32; 3],
        size_mm: [f32; 3],
        initial_density: f32,
        seed: u64,
        device: &Device,
    ) -> Self {
        let grid = HashGrid::new(config.encoding, seed, device);
        let linear = |fan_in: usize, fan_out: usize, k: u64| {
            let mut l = LinearConfig::new(fan_in, fan_out).init(device);
            let bound = 1.0 / (fan_in as f64).sqrt();
            let s = seed ^ (k + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            l.weight = Param::from_tensor(uniform_tensor([fan_in, fan_out], bound, s, device));
            let b = uniform_tensor([1, fan_out], bound, s ^ 0xB1A5, device).reshape([fan_out]);
            l.bias = Some(Param::from_tensor(b));
            l
        };
        let mut hidden = Vec::new();
        let mut width = config.encoding.output_dim();
        for k in 0..config.hidden_layers {
            hidden.push(linear(width, config.hidden, k as u64));
            width = config.hidden;
        }
        let mut output = linear(width, 1, config.hidden_layers as u64);
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

    /// Densities `[N]` at positions `[N, 3]` (mm): one op on wgpu, composed of the encoding
    /// and linear-layer ops elsewhere (`ctadsa_ops::field_op`).
    pub fn forward(&self, positions_mm: Tensor<2>) -> Tensor<1> {
        let device = positions_mm.device();
        let layer = |l: &Linear| Layer {
            weight: l.weight.val(),
            bias: match &l.bias {
                Some(b) => b.val(),
                None => Tensor::zeros([l.weight.dims()[1]], &device),
            },
        };
        let layers: Vec<Layer> = self.hidden.iter().chain(std::iter::once(&self.output)).map(layer).collect();
        let spec = FieldSpec {
            min_mm: self.frame.min_mm,
            inv_size: self.frame.size_mm.map(|s| 1.0 / s),
            grid: self.grid.config,
            // The output activation runs inside the layer's op: one parallel pass each way,
            // where burn's softplus makes seven single-threaded passes over the `[N]` densities.
            output: match self.frame.output {
                OutputActivation::Relu => Activation::Relu,
                OutputActivation::Softplus => Activation::Softplus,
            },
        };
        field_densities(positions_mm, self.grid.tables.val(), &layers, &spec)
    }
}
