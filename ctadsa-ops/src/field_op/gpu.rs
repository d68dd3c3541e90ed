//! The whole opacity field on CubeCL: position → normalised `u` → hash encoding → two hidden
//! ReLU layers → output activation, in one launch forward and three backward (a fill, the
//! per-point backward, the weight-gradient sums), where the composed field (encoding op + three
//! fused linear layers + the normalisation's tensor ops) takes nine forward and seventeen
//! backward.
//!
//! - forward: one workgroup per few points, point after point: one unit per level reads the
//!   corners, one unit per hidden output computes it from the previous layer in shared memory,
//!   the output is a tree sum; it writes each density and `saved` `[N, E + 2H]` (the encoding
//!   and both hidden layers' outputs, which the backward's weight gradients need);
//! - backward, one unit per point: `∂L/∂z` of each layer from the outputs (as the linear
//!   layer's kernels), written to `dz` `[N, 2H + 1]`; the encoding's gradient scattered into
//!   the table gradient atomically and the position gradient through the trilinear weights (as
//!   the hash encoding's kernels);
//! - backward, weight sums: one unit per chunk of [`ROWS_PER_CHUNK`] rows and weight (or bias)
//!   entry of the three layers, adding its partial sum atomically.
//!
//! All gradients of the tables, weights and biases are views of one zero-filled buffer, each
//! segment starting at the device's buffer-offset alignment (one fill for all).

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::{
    Autodiff, AutodiffBackend, Backend, ExtensionType, FloatDType, TensorMetadata, backend_extension,
    tensor::FloatTensor,
};
use burn::tensor::{Shape, TensorData};
use burn_cubecl::cubecl::prelude::*;
use burn_cubecl::tensor::CubeTensor;
use burn_cubecl::{CubeBackend, cubecl};

use ctadsa_render::kernels::{Accumulator, add_f32};

use super::FieldSpec;
use crate::cube::{empty, launch_1d, prepare, tree_sum};
use crate::hash_op::gpu::{corner_at, meta};
use crate::linear_op::Activation;

/// `log₂ UNITS`.
const UNIT_LEVELS: u32 = 6;

/// Rows per partial sum of the weight gradients.
pub const ROWS_PER_CHUNK: usize = 256;

/// The densities `[N]` and what the backward reads: `[N, E + 2H]`.
#[derive(ExtensionType)]
pub struct FieldForward<B: Backend> {
    pub densities: FloatTensor<B>,
    pub saved: FloatTensor<B>,
}

/// Gradients of the field's inputs.
#[derive(ExtensionType)]
pub struct FieldGrads<B: Backend> {
    /// `[N, 3]` (per mm).
    pub positions: FloatTensor<B>,
    /// `[F, R]`.
    pub tables: FloatTensor<B>,
    /// The three layers' weights `[I, O]` and biases `[O]`, in order.
    pub weight_0: FloatTensor<B>,
    pub bias_0: FloatTensor<B>,
    pub weight_1: FloatTensor<B>,
    pub bias_1: FloatTensor<B>,
    pub weight_2: FloatTensor<B>,
    pub bias_2: FloatTensor<B>,
}

/// The fused field (CubeCL only: other backends compose it, see [`super::composed`]).
#[backend_extension(Autodiff, Cube)]
pub trait FieldBackend: Backend {
    /// Densities of `positions` `[N, 3]` (mm) through the encoding `tables` `[F, R]` and the
    /// layers `weight_k` `[I, O]`, `bias_k` `[O]` (hidden width `H`, output width 1).
    #[allow(clippy::too_many_arguments)]
    fn field_forward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        bias_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        bias_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        bias_2: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldForward<Self>;

    /// The gradients for the upstream gradient `grad` `[N]`, from the forward's outputs.
    #[allow(clippy::too_many_arguments)]
    fn field_backward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldGrads<Self>;
}

/// Comptime code of an activation (as the linear layer's kernels).
fn code(act: Activation) -> u32 {
    match act {
        Activation::Identity => 0,
        Activation::Relu => 1,
        Activation::Softplus => 2,
    }
}

/// `frame` `[6]`: the box minimum (mm) and the inverse box size (1/mm) per axis.
#[cube]
fn normalised(positions: &Tensor<f32>, frame: &Tensor<f32>, i: usize) -> (f32, f32, f32) {
    (
        (positions[3 * i] - frame[0]) * frame[3],
        (positions[3 * i + 1] - frame[1]) * frame[4],
        (positions[3 * i + 2] - frame[2]) * frame[5],
    )
}

/// Units of a workgroup of the per-point kernels: one per hidden output (and encoding level).
pub const UNITS: usize = 64;
/// Points each workgroup of the per-point kernels takes in turn.
pub const POINTS_PER_CUBE: usize = 8;

/// One workgroup of [`UNITS`] units per [`POINTS_PER_CUBE`] points, point after point: the
/// units of the first `levels` read one level's corners each, then unit `o` computes output
/// `o` of each hidden layer from the previous layer in shared memory, and the output layer's
/// sum is a tree over the units.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn field_forward_kernel(
    positions: &Tensor<f32>,
    frame: &Tensor<f32>,
    tables: &Tensor<f32>,
    meta: &Tensor<f32>,
    weight_0: &Tensor<f32>,
    bias_0: &Tensor<f32>,
    weight_1: &Tensor<f32>,
    bias_1: &Tensor<f32>,
    weight_2: &Tensor<f32>,
    bias_2: &Tensor<f32>,
    densities: &mut Tensor<f32>,
    saved: &mut Tensor<f32>,
    n: u32,
    stride: u32,
    mask: u32,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] hidden: usize,
    #[comptime] act: u32,
) {
    let u = UNIT_POS as usize;
    let width = levels * features;
    let row_len = width + 2 * hidden;
    let mut enc = Shared::<[f32]>::new_slice(UNITS);
    let mut h0 = Shared::<[f32]>::new_slice(UNITS);
    let mut sums = Shared::<[f32]>::new_slice(UNITS);
    for t in 0..POINTS_PER_CUBE {
        let i = CUBE_POS * POINTS_PER_CUBE + t;
        let live = i < n as usize;
        let base = i * row_len;
        if live && u < levels {
            let (ux, uy, uz) = normalised(positions, frame, i);
            let mut acc = Array::<f32>::new(features);
            for f in 0..features {
                acc[f] = 0.0f32;
            }
            for k in 0..8u32 {
                let (row, w, _a, _b, _c) = corner_at(ux, uy, uz, meta, u, k, mask);
                for f in 0..features {
                    acc[f] += w * tables[f * (stride as usize) + row as usize];
                }
            }
            for f in 0..features {
                enc[u * features + f] = acc[f];
                saved[base + u * features + f] = acc[f];
            }
        }
        sync_cube();
        if live && u < hidden {
            let mut acc = 0.0f32;
            for j in 0..width {
                acc += enc[j] * weight_0[j * hidden + u];
            }
            let v = f32::max(acc + bias_0[u], 0.0f32);
            h0[u] = v;
            saved[base + width + u] = v;
        }
        sync_cube();
        let mut part = 0.0f32;
        if live && u < hidden {
            let mut acc = 0.0f32;
            for j in 0..hidden {
                acc += h0[j] * weight_1[j * hidden + u];
            }
            let v = f32::max(acc + bias_1[u], 0.0f32);
            saved[base + width + hidden + u] = v;
            part = v * weight_2[u];
        }
        sums[u] = part;
        tree_sum(&mut sums, UNITS, UNIT_LEVELS);
        if live && u == 0 {
            let v = sums[0] + bias_2[0];
            let mut y = v;
            if act == 1u32 {
                y = f32::max(v, 0.0f32);
            }
            if act == 2u32 {
                y = f32::max(v, 0.0f32) + f32::log1p(f32::exp(-f32::abs(v)));
            }
            densities[i] = y;
        }
    }
}

/// The backward, one unit per point (measured faster on an H200 than a workgroup per point
/// laid out as the forward, whose table scatter keeps only `levels` units busy).
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn field_backward_kernel(
    positions: &Tensor<f32>,
    frame: &Tensor<f32>,
    tables: &Tensor<f32>,
    meta: &Tensor<f32>,
    weight_0: &Tensor<f32>,
    weight_1: &Tensor<f32>,
    weight_2: &Tensor<f32>,
    saved: &Tensor<f32>,
    densities: &Tensor<f32>,
    grad: &Tensor<f32>,
    grad_positions: &mut Tensor<f32>,
    dz: &mut Tensor<f32>,
    grads_f32: &mut Tensor<Atomic<f32>>,
    grads_u32: &mut Tensor<Atomic<u32>>,
    n: u32,
    stride: u32,
    mask: u32,
    #[comptime] levels: usize,
    #[comptime] features: usize,
    #[comptime] hidden: usize,
    #[comptime] act: u32,
    #[comptime] native: bool,
) {
    let i = ABSOLUTE_POS;
    if i >= n as usize {
        terminate!();
    }
    let width = levels * features;
    let row_len = width + 2 * hidden;
    let base = i * row_len;
    let dz_len = 2 * hidden + 1;
    let dz_base = i * dz_len;
    // The output layer: ∂L/∂z from the density (`Activation::gradient`).
    let g = grad[i];
    let mut dz_out = g;
    if act == 1u32 {
        dz_out = select(densities[i] > 0.0f32, g, 0.0f32);
    }
    if act == 2u32 {
        dz_out = g * (1.0f32 - f32::exp(-densities[i]));
    }
    dz[dz_base + 2 * hidden] = dz_out;
    // The second hidden layer.
    let mut dz1 = Array::<f32>::new(hidden);
    for o in 0..hidden {
        let d = select(saved[base + width + hidden + o] > 0.0f32, weight_2[o] * dz_out, 0.0f32);
        dz1[o] = d;
        dz[dz_base + hidden + o] = d;
    }
    // The first hidden layer.
    let mut dz0 = Array::<f32>::new(hidden);
    for j in 0..hidden {
        let mut acc = 0.0f32;
        for o in 0..hidden {
            acc += weight_1[j * hidden + o] * dz1[o];
        }
        let d = select(saved[base + width + j] > 0.0f32, acc, 0.0f32);
        dz0[j] = d;
        dz[dz_base + j] = d;
    }
    // The encoding.
    let mut denc = Array::<f32>::new(width);
    for e in 0..width {
        let mut acc = 0.0f32;
        for o in 0..hidden {
            acc += weight_0[e * hidden + o] * dz0[o];
        }
        denc[e] = acc;
    }
    let (ux, uy, uz) = normalised(positions, frame, i);
    let mut gx = 0.0f32;
    let mut gy = 0.0f32;
    let mut gz = 0.0f32;
    for l in 0..levels {
        for k in 0..8u32 {
            let (row, w, dx, dy, dzw) = corner_at(ux, uy, uz, meta, l, k, mask);
            for f in 0..features {
                let ge = denc[l * features + f];
                let index = f * (stride as usize) + row as usize;
                let t = tables[index];
                gx += dx * ge * t;
                gy += dy * ge * t;
                gz += dzw * ge * t;
                add_f32(grads_f32, grads_u32, index, w * ge, native);
            }
        }
    }
    grad_positions[3 * i] = gx * frame[3];
    grad_positions[3 * i + 1] = gy * frame[4];
    grad_positions[3 * i + 2] = gz * frame[5];
}

/// Where each layer's weight and bias gradients start in the gradient buffer (elements).
#[derive(CubeType, CubeLaunch)]
pub struct Segments {
    weight_0: u32,
    bias_0: u32,
    weight_1: u32,
    bias_1: u32,
    weight_2: u32,
    bias_2: u32,
}

/// Layer `k`'s place in the weight-gradient sums: `(first entry, inputs I, outputs O, offset
/// of its inputs in a `saved` row, offset of its ∂L/∂z in a `dz` row, weight segment, bias
/// segment)`.
#[cube]
fn layer_of(
    e: usize,
    width: usize,
    hidden: usize,
    segments: Segments,
) -> (usize, usize, usize, usize, usize, usize, usize) {
    let first_1 = (width + 1) * hidden;
    let first_2 = first_1 + (hidden + 1) * hidden;
    let mut first = 0usize;
    let mut weight_segment = segments.weight_0 as usize;
    let mut bias_segment = segments.bias_0 as usize;
    let mut inputs = width;
    let mut outputs = hidden;
    let mut x_offset = 0usize;
    let mut dz_offset = 0usize;
    if e >= first_1 {
        first = first_1;
        weight_segment = segments.weight_1 as usize;
        bias_segment = segments.bias_1 as usize;
        inputs = hidden;
        x_offset = width;
        dz_offset = hidden;
    }
    if e >= first_2 {
        first = first_2;
        weight_segment = segments.weight_2 as usize;
        bias_segment = segments.bias_2 as usize;
        outputs = 1;
        x_offset = width + hidden;
        dz_offset = 2 * hidden;
    }
    (first, inputs, outputs, x_offset, dz_offset, weight_segment, bias_segment)
}

/// One unit per (chunk, entry): `Σ_{r in chunk} x[r, i] · dz[r, o]` (or `Σ dz[r, o]` for the
/// bias row `i = I`), added to the entry's gradient.
#[cube(launch)]
#[allow(clippy::too_many_arguments)]
fn field_weight_gradient_kernel(
    saved: &Tensor<f32>,
    dz: &Tensor<f32>,
    segments: Segments,
    grads_f32: &mut Tensor<Atomic<f32>>,
    grads_u32: &mut Tensor<Atomic<u32>>,
    rows: u32,
    entries: u32,
    len: u32,
    #[comptime] width: usize,
    #[comptime] hidden: usize,
    #[comptime] chunk: usize,
    #[comptime] native: bool,
) {
    let id = ABSOLUTE_POS;
    if id >= len as usize {
        terminate!();
    }
    let e = id % (entries as usize);
    let c = id / (entries as usize);
    let (first, inputs, outputs, x_offset, dz_offset, weight_segment, bias_segment) =
        layer_of(e, width, hidden, segments);
    let local = e - first;
    let i = local / outputs;
    let o = local % outputs;
    let row_len = width + 2 * hidden;
    let dz_len = 2 * hidden + 1;
    let start = c * chunk;
    let mut end = start + chunk;
    if end > rows as usize {
        end = rows as usize;
    }
    let mut acc = 0.0f32;
    if i == inputs {
        for r in start..end {
            acc += dz[r * dz_len + dz_offset + o];
        }
        add_f32(grads_f32, grads_u32, bias_segment + o, acc, native);
    } else {
        for r in start..end {
            acc += saved[r * row_len + x_offset + i] * dz[r * dz_len + dz_offset + o];
        }
        add_f32(grads_f32, grads_u32, weight_segment + i * outputs + o, acc, native);
    }
}

/// Workgroups of the per-point kernels for `n` points (a grid of at most 65,535 × 65,535).
fn per_point_cubes(n: usize) -> CubeCount {
    let cubes = n.div_ceil(POINTS_PER_CUBE) as u32;
    CubeCount::Static(cubes.min(65_535), cubes.div_ceil(65_535), 1)
}

/// `[min (mm); 1 / size (1/mm)]` `[6]` and the encoding's level table.
fn frame_and_meta(spec: &FieldSpec, like: &CubeTensor) -> (CubeTensor, CubeTensor) {
    let frame: Vec<f32> = spec.min_mm.iter().chain(spec.inv_size.iter()).copied().collect();
    let frame = CubeBackend::float_from_data(TensorData::new(frame, [6]), &like.device);
    (frame, meta(&spec.grid, like))
}

impl FieldBackend for CubeBackend {
    fn field_forward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        bias_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        bias_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        bias_2: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldForward<Self> {
        let positions = prepare(positions);
        let n = positions.shape()[0];
        let hidden = weight_1.shape()[0];
        let width = spec.grid.output_dim();
        let densities = empty(vec![n], &positions);
        let saved = empty(vec![n, width + 2 * hidden], &positions);
        if n == 0 {
            return FieldForward { densities, saved };
        }
        let (frame, meta) = frame_and_meta(&spec, &positions);
        field_forward_kernel::launch(
            &positions.client,
            per_point_cubes(n),
            CubeDim::new_1d(UNITS as u32),
            positions.clone().into_tensor_arg(),
            frame.into_tensor_arg(),
            prepare(tables).into_tensor_arg(),
            meta.into_tensor_arg(),
            prepare(weight_0).into_tensor_arg(),
            prepare(bias_0).into_tensor_arg(),
            prepare(weight_1).into_tensor_arg(),
            prepare(bias_1).into_tensor_arg(),
            prepare(weight_2).into_tensor_arg(),
            prepare(bias_2).into_tensor_arg(),
            densities.clone().into_tensor_arg(),
            saved.clone().into_tensor_arg(),
            n as u32,
            spec.grid.rows() as u32,
            (spec.grid.table_size() - 1) as u32,
            spec.grid.levels,
            spec.grid.features,
            hidden,
            code(spec.output),
        );
        FieldForward { densities, saved }
    }

    fn field_backward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldGrads<Self> {
        let positions = prepare(positions);
        let tables = prepare(tables);
        let n = positions.shape()[0];
        let hidden = weight_1.shape()[0];
        let width = spec.grid.output_dim();
        // Segments of the one gradient buffer, each aligned for a view.
        let align = (positions.client.properties().memory.alignment as usize / 4).max(1);
        let table_len = tables.shape().num_elements();
        let lens = [table_len, width * hidden, hidden, hidden * hidden, hidden, hidden, 1];
        let mut starts = [0usize; 7];
        let mut total = 0;
        for (start, len) in starts.iter_mut().zip(lens) {
            *start = total;
            total += len.div_ceil(align) * align;
        }
        let buffer = CubeBackend::float_zeros(Shape::new([total]), &positions.device, FloatDType::F32);
        let grad_positions = empty(vec![n, 3], &positions);
        if n > 0 {
            let (frame, meta) = frame_and_meta(&spec, &positions);
            let dz = empty(vec![n, 2 * hidden + 1], &positions);
            let (weight_0, weight_1, weight_2) = (prepare(weight_0), prepare(weight_1), prepare(weight_2));
            let (saved, densities, grad) = (prepare(saved), prepare(densities), prepare(grad));
            let acc = Accumulator::new(&buffer, spec.grid.f32_add);
            let (count, dim) = launch_1d(&positions, n, 64);
            field_backward_kernel::launch(
                &positions.client,
                count,
                dim,
                positions.clone().into_tensor_arg(),
                frame.into_tensor_arg(),
                tables.clone().into_tensor_arg(),
                meta.into_tensor_arg(),
                weight_0.into_tensor_arg(),
                weight_1.into_tensor_arg(),
                weight_2.into_tensor_arg(),
                saved.clone().into_tensor_arg(),
                densities.into_tensor_arg(),
                grad.into_tensor_arg(),
                grad_positions.clone().into_tensor_arg(),
                dz.clone().into_tensor_arg(),
                acc.as_f32.clone().into_tensor_arg(),
                acc.as_u32.clone().into_tensor_arg(),
                n as u32,
                spec.grid.rows() as u32,
                (spec.grid.table_size() - 1) as u32,
                spec.grid.levels,
                spec.grid.features,
                hidden,
                code(spec.output),
                acc.native,
            );
            let segments = SegmentsLaunch::new(
                starts[1] as u32,
                starts[2] as u32,
                starts[3] as u32,
                starts[4] as u32,
                starts[5] as u32,
                starts[6] as u32,
            );
            let entries = (width + 1) * hidden + (hidden + 1) * hidden + hidden + 1;
            let len = n.div_ceil(ROWS_PER_CHUNK) * entries;
            let (count, dim) = launch_1d(&positions, len, 256);
            field_weight_gradient_kernel::launch(
                &positions.client,
                count,
                dim,
                saved.into_tensor_arg(),
                dz.into_tensor_arg(),
                segments,
                acc.as_f32.into_tensor_arg(),
                acc.as_u32.into_tensor_arg(),
                n as u32,
                entries as u32,
                len as u32,
                width,
                hidden,
                ROWS_PER_CHUNK,
                acc.native,
            );
        }
        // A view from an aligned start to the buffer's end (burn's slice then makes no copy),
        // told its own length: the kernels that read it index by its shape.
        let view = |k: usize, shape: Vec<usize>| {
            let mut part = CubeBackend::float_slice(buffer.clone(), &[burn::tensor::Slice::from(starts[k]..total)]);
            part.meta.shape = Shape::new([lens[k]]);
            CubeBackend::float_reshape(part, Shape::from(shape))
        };
        FieldGrads {
            positions: grad_positions,
            tables: view(0, tables.shape().to_vec()),
            weight_0: view(1, vec![width, hidden]),
            bias_0: view(2, vec![hidden]),
            weight_1: view(3, vec![hidden, hidden]),
            bias_1: view(4, vec![hidden]),
            weight_2: view(5, vec![hidden, 1]),
            bias_2: view(6, vec![1]),
        }
    }
}

#[derive(Debug)]
struct FieldBackward;

/// What the backward reads: positions, tables, the three weights, `saved`, the densities.
type FieldState<B> = (FloatTensor<B>, FloatTensor<B>, [FloatTensor<B>; 3], FloatTensor<B>, FloatTensor<B>, FieldSpec);

impl<B: Backend + FieldBackend> Backward<B, 8> for FieldBackward {
    type State = FieldState<B>;

    fn backward(self, ops: Ops<Self::State, 8>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let grad = grads.consume::<B>(&ops.node);
        let (positions, tables, [w0, w1, w2], saved, densities, spec) = ops.state;
        let g = B::field_backward(positions, tables, w0, w1, w2, saved, densities, grad, spec);
        let values = [g.positions, g.tables, g.weight_0, g.bias_0, g.weight_1, g.bias_1, g.weight_2, g.bias_2];
        for (parent, value) in ops.parents.into_iter().zip(values) {
            if let Some(node) = parent {
                grads.register::<B>(node.id, value);
            }
        }
    }
}

impl<B: Backend + FieldBackend, C: CheckpointStrategy> FieldBackend for Autodiff<B, C> {
    fn field_forward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        bias_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        bias_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        bias_2: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldForward<Self> {
        let nodes = [
            positions.node(),
            tables.node(),
            weight_0.node(),
            bias_0.node(),
            weight_1.node(),
            bias_1.node(),
            weight_2.node(),
            bias_2.node(),
        ];
        let prep = FieldBackward.prepare::<C>(nodes).compute_bound().stateful();
        let (positions, tables) = (positions.into_primitive(), tables.into_primitive());
        let (w0, w1, w2) = (weight_0.into_primitive(), weight_1.into_primitive(), weight_2.into_primitive());
        let out = B::field_forward(
            positions.clone(),
            tables.clone(),
            w0.clone(),
            bias_0.into_primitive(),
            w1.clone(),
            bias_1.into_primitive(),
            w2.clone(),
            bias_2.into_primitive(),
            spec,
        );
        let saved = Self::from_inner(out.saved.clone());
        let densities = match prep {
            OpsKind::Tracked(prep) => {
                prep.finish((positions, tables, [w0, w1, w2], out.saved, out.densities.clone(), spec), out.densities)
            }
            OpsKind::UnTracked(prep) => prep.finish(out.densities),
        };
        FieldForward { densities, saved }
    }

    fn field_backward(
        positions: FloatTensor<Self>,
        tables: FloatTensor<Self>,
        weight_0: FloatTensor<Self>,
        weight_1: FloatTensor<Self>,
        weight_2: FloatTensor<Self>,
        saved: FloatTensor<Self>,
        densities: FloatTensor<Self>,
        grad: FloatTensor<Self>,
        spec: FieldSpec,
    ) -> FieldGrads<Self> {
        let g = B::field_backward(
            positions.into_primitive(),
            tables.into_primitive(),
            weight_0.into_primitive(),
            weight_1.into_primitive(),
            weight_2.into_primitive(),
            saved.into_primitive(),
            densities.into_primitive(),
            grad.into_primitive(),
            spec,
        );
        FieldGrads {
            positions: Self::from_inner(g.positions),
            tables: Self::from_inner(g.tables),
            weight_0: Self::from_inner(g.weight_0),
            bias_0: Self::from_inner(g.bias_0),
            weight_1: Self::from_inner(g.weight_1),
            bias_1: Self::from_inner(g.bias_1),
            weight_2: Self::from_inner(g.weight_2),
            bias_2: Self::from_inner(g.bias_2),
        }
    }
}
