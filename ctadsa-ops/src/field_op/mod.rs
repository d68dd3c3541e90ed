//! The opacity field's densities at points: the positions normalised into the field's box, the
//! hash encoding, hidden ReLU layers and the output activation.
//!
//! On a CubeCL device (wgpu), for the field the method trains (two hidden layers of the same
//! width `H ≤ 64`, an encoding of `E ≤ 64` features, one output), the whole field is one op of
//! one launch forward and three backward (`gpu.rs`); otherwise, and always on NdArray, it is
//! composed of the hash-encoding op and the fused linear layers ([`composed`]), which is also
//! the fused op's oracle (`tests/ops_wgpu.rs`).

#[cfg(feature = "wgpu")]
mod gpu;

use burn::tensor::{Tensor, TensorData};

use crate::hash_grid::HashGridConfig;
use crate::hash_op::hash_encode;
use crate::linear_op::{Activation, fused_linear};

/// The widest encoding and hidden layer the fused op takes (its per-unit arrays).
pub const FUSED_MAX_WIDTH: usize = 64;

/// What the field's parameters do not say: its box and activations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSpec {
    /// The box minimum (mm): `u = (x − min) · inv_size`.
    pub min_mm: [f32; 3],
    /// The inverse box size (1/mm).
    pub inv_size: [f32; 3],
    /// The encoding.
    pub grid: HashGridConfig,
    /// The output layer's activation (the hidden layers' is ReLU).
    pub output: Activation,
}

/// One linear layer: `weight` `[I, O]`, `bias` `[O]`.
pub struct Layer {
    pub weight: Tensor<2>,
    pub bias: Tensor<1>,
}

/// Densities `[N]` at `positions` `[N, 3]` (mm) from the encoding `tables` `[F, R]` and
/// `layers` (hidden ReLU layers, then the output layer of width 1 with `spec.output`).
/// Differentiable in the positions, the tables and every layer.
pub fn field_densities(positions: Tensor<2>, tables: Tensor<2>, layers: &[Layer], spec: &FieldSpec) -> Tensor<1> {
    #[cfg(feature = "wgpu")]
    if fusable(&positions, &tables, layers, spec) {
        return fused(positions, tables, layers, spec);
    }
    composed(positions, tables, layers, spec)
}

/// The field composed of the encoding op and the fused linear layers.
pub fn composed(positions: Tensor<2>, tables: Tensor<2>, layers: &[Layer], spec: &FieldSpec) -> Tensor<1> {
    let n = positions.dims()[0];
    let device = positions.device();
    let row = |v: [f32; 3]| Tensor::<1>::from_data(TensorData::new(v.to_vec(), [3]), &device).reshape([1, 3]);
    let u = (positions - row(spec.min_mm)) * row(spec.inv_size);
    let mut x = hash_encode(u, tables, spec.grid);
    let last = layers.len().saturating_sub(1);
    for (k, layer) in layers.iter().enumerate() {
        let act = if k == last { spec.output } else { Activation::Relu };
        x = fused_linear(x, layer.weight.clone(), layer.bias.clone(), act);
    }
    x.reshape([n])
}

/// Whether the fused op takes this field on this device.
#[cfg(feature = "wgpu")]
fn fusable(positions: &Tensor<2>, tables: &Tensor<2>, layers: &[Layer], spec: &FieldSpec) -> bool {
    let [w0, w1, w2] = match layers {
        [a, b, c] => [a.weight.dims(), b.weight.dims(), c.weight.dims()],
        _ => return false,
    };
    let (width, hidden) = (spec.grid.output_dim(), w1[0]);
    crate::cube::runs_on_cube(&positions.device())
        && tables.dims() == [spec.grid.features, spec.grid.rows()]
        && w0 == [width, hidden]
        && w1 == [hidden, hidden]
        && w2 == [hidden, 1]
        && (1..=FUSED_MAX_WIDTH).contains(&width)
        && (1..=FUSED_MAX_WIDTH).contains(&hidden)
}

#[cfg(feature = "wgpu")]
fn fused(positions: Tensor<2>, tables: Tensor<2>, layers: &[Layer], spec: &FieldSpec) -> Tensor<1> {
    use burn::backend::Dispatch;
    use gpu::FieldBackend;
    let [l0, l1, l2] = layers else { return composed(positions, tables, layers, spec) };
    let out = <Dispatch as FieldBackend>::field_forward(
        positions.into_dispatch(),
        tables.into_dispatch(),
        l0.weight.clone().into_dispatch(),
        l0.bias.clone().into_dispatch(),
        l1.weight.clone().into_dispatch(),
        l1.bias.clone().into_dispatch(),
        l2.weight.clone().into_dispatch(),
        l2.bias.clone().into_dispatch(),
        *spec,
    );
    Tensor::from_dispatch(out.densities)
}
