//! Multiresolution hash encoding (Müller et al., instant-NGP) as burn tensor operations.
//!
//! Level `l` has resolution `r_l = ⌊base · growth^l⌋` cells per unit; a point `u ∈ [0, 1)³`
//! falls in cell `⌊u r_l⌋` and reads the `features`-vectors stored at the cell's 8 corners,
//! trilinearly weighted. Corner `c` is stored at `c_x + c_y (r+1) + c_z (r+1)²` when the level's
//! grid fits in `T` rows (dense: the level has `(r+1)³` rows), else at
//! `(c_x ⊕ c_y·P₁ ⊕ c_z·P₂) mod T` (hashed: `T` rows). All levels' tables are one
//! `[features, R]` parameter (feature-major, levels one after another, `R` = the sum of the
//! levels' rows: no unused padding on the dense levels), read with one `gather` along its last
//! axis; gradients reach the table (scatter-add) and the positions (through the trilinear
//! weights).

use burn::module::{Module, Param};
use burn::tensor::{Device, Int, Tensor, TensorData};

pub use crate::hash_op::{HASH_P1, HASH_P2, HashGridConfig};

/// The encoding's parameter (all level tables) and settings.
#[derive(Module, Debug)]
pub struct HashGrid {
    /// `[features, R]` ([`HashGridConfig::rows`]).
    pub tables: Param<Tensor<2>>,
    #[module(skip)]
    pub config: HashGridConfig,
}

impl HashGrid {
    /// Tables initialised uniformly in ±1e-4 (as instant-NGP), from `seed` (the same seed gives
    /// the same tables, whatever else draws random numbers). The values are those the padded
    /// `[features, levels · T]` layout drew, compacted, so that runs are unchanged by the layout.
    pub fn new(config: HashGridConfig, seed: u64, device: &Device) -> Self {
        let padded = crate::random::uniform_values(config.features * config.padded_rows(), 1e-4, seed);
        let tables = config.compact_table(&padded);
        let tables = Tensor::from_data(TensorData::new(tables, [config.features, config.rows()]), device);
        Self { tables: Param::from_tensor(tables), config }
    }

    /// Encodes points `u` `[N, 3]` in `[0, 1]³` (clamped) into `[N, levels · features]`
    /// with the backend op (CPU or GPU kernels, hand-written backward).
    pub fn forward(&self, u: Tensor<2>) -> Tensor<2> {
        crate::hash_op::hash_encode(u, self.tables.val(), self.config)
    }

    /// The same encoding composed of plain burn tensor operations (autodiff through them);
    /// slower, kept as a second implementation for tests.
    pub fn forward_tensor_ops(&self, u: Tensor<2>) -> Tensor<2> {
        let c = self.config;
        let device = u.device();
        let n = u.dims()[0];
        let (levels, feats) = (c.levels, c.features);
        if n == 0 {
            return Tensor::zeros([0, c.output_dim()], &device);
        }
        let u = u.clamp(0.0, 1.0 - 1e-6);
        let res: Vec<f32> = (0..levels).map(|l| c.resolution(l) as f32).collect();
        let res = Tensor::<1>::from_data(TensorData::new(res, [levels]), &device).reshape([1, levels, 1]);
        let pos = u.reshape([n, 1, 3]) * res; // [N, L, 3]
        let cell_f = pos.clone().floor();
        let frac = pos - cell_f.clone().detach(); // [N, L, 3]
        let cell = cell_f.detach().int(); // [N, L, 3]
        // Corner offsets [8, 3].
        let offsets: Vec<i64> = (0..8).flat_map(|k| [k & 1, (k >> 1) & 1, (k >> 2) & 1]).collect();
        let off_i =
            Tensor::<3, Int>::from_data(TensorData::new(offsets.clone(), [1, 8, 3]), &device).reshape([1, 1, 8, 3]);
        let off_f: Tensor<4> = Tensor::from_data(
            TensorData::new(offsets.iter().map(|&v| v as f32).collect::<Vec<_>>(), [1, 1, 8, 3]),
            &device,
        );
        let corner = cell.reshape([n, levels, 1, 3]) + off_i; // [N, L, 8, 3]
        let cx = corner.clone().slice([0..n, 0..levels, 0..8, 0..1]).reshape([n, levels, 8]);
        let cy = corner.clone().slice([0..n, 0..levels, 0..8, 1..2]).reshape([n, levels, 8]);
        let cz = corner.slice([0..n, 0..levels, 0..8, 2..3]).reshape([n, levels, 8]);
        // Per-level constants: dense strides (0 on hashed levels), dense mask, level offset.
        let t = c.table_size();
        let mut sy = Vec::new();
        let mut sz = Vec::new();
        let mut dense = Vec::new();
        let mut base = Vec::new();
        for l in 0..levels {
            let r1 = c.resolution(l) + 1;
            let d = c.dense(l);
            sy.push(if d { r1 } else { 0 });
            sz.push(if d { r1 * r1 } else { 0 });
            dense.push(d as i64);
            base.push(c.level_offset(l) as i64);
        }
        let lvl = |v: Vec<i64>| Tensor::<3, Int>::from_data(TensorData::new(v, [1, levels, 1]), &device);
        let (sy, sz, dense, base) = (lvl(sy), lvl(sz), lvl(dense), lvl(base));
        let dense_idx = cx.clone() + cy.clone() * sy + cz.clone() * sz;
        let hash_idx =
            (cx.bitwise_xor(cy.mul_scalar(HASH_P1)).bitwise_xor(cz.mul_scalar(HASH_P2))).bitwise_and_scalar(t - 1);
        let idx = dense_idx * dense.clone() + hash_idx * (dense.neg().add_scalar(1)) + base; // [N, L, 8]
        let m = n * levels * 8;
        let idx = idx.reshape([1, m]).repeat_dim(0, feats); // [F, M]
        let rows = self.tables.val().gather(1, idx); // [F, M]
        let rows = rows.swap_dims(0, 1).reshape([n, levels, 8, feats]);
        // Trilinear weights Π_d (o_d f_d + (1 − o_d)(1 − f_d)).
        let f = frac.reshape([n, levels, 1, 3]);
        let w = f.clone() * off_f.clone() + (f.neg().add_scalar(1.0)) * (off_f.neg().add_scalar(1.0)); // [N,L,8,3]
        let w = w.clone().slice([0..n, 0..levels, 0..8, 0..1])
            * w.clone().slice([0..n, 0..levels, 0..8, 1..2])
            * w.slice([0..n, 0..levels, 0..8, 2..3]); // [N, L, 8, 1]
        (rows * w).sum_dim(2).reshape([n, levels * feats])
    }
}

/// A direct per-point evaluation of the same encoding from the table values (host, f64), for
/// tests: `tables` is `[features, R]` row-major, `u` one point.
pub fn encode_reference(config: &HashGridConfig, tables: &[f32], u: [f64; 3]) -> Vec<f64> {
    let t = config.table_size();
    let mut out = Vec::with_capacity(config.output_dim());
    for l in 0..config.levels {
        let r = config.resolution(l);
        let p = u.map(|v| v.clamp(0.0, 1.0 - 1e-6) * r as f64);
        let cell = p.map(|v| v.floor() as i64);
        let frac = [0, 1, 2].map(|d| p[d] - cell[d] as f64);
        let mut acc = vec![0.0; config.features];
        for k in 0..8i64 {
            let o = [k & 1, (k >> 1) & 1, (k >> 2) & 1];
            let cc = [0, 1, 2].map(|d| cell[d] + o[d]);
            let idx = if config.dense(l) {
                cc[0] + cc[1] * (r + 1) + cc[2] * (r + 1) * (r + 1)
            } else {
                (cc[0] ^ (cc[1] * HASH_P1) ^ (cc[2] * HASH_P2)) & (t - 1)
            };
            let w: f64 = (0..3).map(|d| if o[d] == 1 { frac[d] } else { 1.0 - frac[d] }).product();
            let row = config.level_offset(l) + idx as usize;
            let stride = config.rows();
            for (f, a) in acc.iter_mut().enumerate() {
                *a += w * tables[f * stride + row] as f64;
            }
        }
        out.extend(acc);
    }
    out
}
