//! CPU kernels of the fused linear layer on host slices, row-major: matrix products through
//! the `gemm` crate (transposed operands are strided views, never copies) on fixed row blocks in
//! parallel, bias and ReLU in the same pass. The blocks do not depend on the thread count, and
//! the weight gradient sums its per-block products in block order, so results are the same for
//! any number of threads.

use std::borrow::Cow;
use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::Activation;
use crate::par_buffer::zeroed;

/// Rows per block of the bias-gradient sum (fixed, so the sum is the same for any thread count).
const BIAS_BLOCK_ROWS: usize = 4096;
/// Rows per parallel block of the matrix products.
const PRODUCT_BLOCK_ROWS: usize = 2048;

/// A host matrix `rows × cols` whose element `(r, c)` is `data[r·row_stride + c·col_stride]`.
#[derive(Debug, Clone, Copy)]
struct MatRef<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    row_stride: usize,
    col_stride: usize,
}

impl<'a> MatRef<'a> {
    /// The row-major `rows × cols` matrix `data`.
    fn new(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self { data, rows, cols, row_stride: cols, col_stride: 1 }
    }

    /// The transpose (a strided view of the same values).
    fn t(self) -> Self {
        Self { rows: self.cols, cols: self.rows, row_stride: self.col_stride, col_stride: self.row_stride, ..self }
    }

    /// Whether every element lies inside `data`.
    fn in_bounds(&self) -> bool {
        self.rows == 0
            || self.cols == 0
            || (self.rows - 1) * self.row_stride + (self.cols - 1) * self.col_stride < self.data.len()
    }
}

/// `dst = a · b`, `dst` row-major `[a.rows, b.cols]`, on the calling thread.
///
/// Panics when the shapes do not match or a view reaches outside its slice (the callers pass
/// the op's checked shapes).
fn matmul(dst: &mut [f32], a: MatRef, b: MatRef) {
    check_shapes(dst.len(), a, b);
    // SAFETY: `check_shapes` bounds every element gemm reads (`a`, `b`) and writes (`dst`);
    // `dst` is borrowed mutably, so it aliases neither operand.
    unsafe { gemm_into(dst.as_mut_ptr(), a, b) }
}

/// `dst = a · b` into memory that may be uninitialised: every element of `dst` is written and
/// none is read (a buffer that is overwritten whole need not be cleared first); returns `dst`,
/// now initialised. Panics as [`matmul`].
fn matmul_overwrite<'a>(dst: &'a mut [MaybeUninit<f32>], a: MatRef, b: MatRef) -> &'a mut [f32] {
    check_shapes(dst.len(), a, b);
    let len = dst.len();
    let ptr = dst.as_mut_ptr().cast::<f32>();
    // SAFETY: as in `matmul`; `gemm_into` writes every element of the `m × n` block without
    // reading it, so the uninitialised values are never read, and afterwards all `len` of them
    // are initialised f32 values, borrowed mutably through `dst` for `'a`.
    unsafe {
        gemm_into(ptr, a, b);
        std::slice::from_raw_parts_mut(ptr, len)
    }
}

/// Panics unless `a · b` is defined, both views lie inside their slices and the product has
/// `dst_len` elements.
fn check_shapes(dst_len: usize, a: MatRef, b: MatRef) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert!(
        b.rows == k && dst_len == m * n && a.in_bounds() && b.in_bounds(),
        "matmul: [{m}, {k}] · [{}, {n}] into {dst_len} values",
        b.rows
    );
}

/// gemm's product of `a` and `b` into the row-major `[a.rows, b.cols]` block at `dst`, which it
/// writes whole and never reads: without `read_dst` gemm's destination factor is zero, and its
/// kernels then store the product without loading the destination (also when `k` is 0).
///
/// # Safety
/// `dst` must be valid for writes of `a.rows · b.cols` values and must not overlap `a` or `b`;
/// the views must lie inside their slices and match in shape ([`check_shapes`]).
unsafe fn gemm_into(dst: *mut f32, a: MatRef, b: MatRef) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    if m == 0 || n == 0 {
        return;
    }
    // SAFETY: the caller's contract.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            n as isize,
            false,
            a.data.as_ptr(),
            a.col_stride as isize,
            a.row_stride as isize,
            b.data.as_ptr(),
            b.col_stride as isize,
            b.row_stride as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        )
    }
}

/// `y = act(x w + b)` for `x` `[n, i]`, `w` `[i, o]`, `b` `[o]`: `[n, o]`. Each row block's
/// product overwrites its rows, and the bias and the activation follow in one pass while the
/// block is in cache (`x w + b` rounded once, as gemm adding onto a bias-filled block would).
pub fn forward(x: &[f32], w: &[f32], b: &[f32], n: usize, act: Activation) -> Vec<f32> {
    let o = b.len();
    let i = w.len() / o.max(1);
    let mut y: Vec<f32> = Vec::with_capacity(n * o);
    if o > 0 {
        let wm = MatRef::new(w, i, o);
        y.spare_capacity_mut()[..n * o].par_chunks_mut(PRODUCT_BLOCK_ROWS * o).enumerate().with_max_len(1).for_each(
            |(block, d)| {
                let rows = d.len() / o;
                let first = block * PRODUCT_BLOCK_ROWS;
                let d = matmul_overwrite(d, MatRef::new(&x[first * i..(first + rows) * i], rows, i), wm);
                for row in d.chunks_exact_mut(o) {
                    for (v, &bias) in row.iter_mut().zip(b) {
                        *v = act.apply(*v + bias);
                    }
                }
            },
        );
    }
    // SAFETY: the capacity is `n · o`, and the row blocks above cover all of it, each written
    // whole by `matmul_overwrite`.
    unsafe { y.set_len(n * o) };
    y
}

/// What one task of [`backward`] sums over its rows: the weight gradient's product per
/// `PRODUCT_BLOCK_ROWS` block, in block order, and the bias gradient's column sums.
struct BlockSums {
    weight: Vec<Vec<f32>>,
    bias: Vec<f32>,
}

/// Gradients of the fused layer for the upstream gradient `gy` `[n, o]`, given the input `x`
/// `[n, i]`, weight `w` `[i, o]` and the forward output `y` (which gives the activation's
/// slope, [`Activation::gradient`]):
/// `(∂x [n, i], ∂w [i, o], ∂b [o])`.
///
/// One task per `BIAS_BLOCK_ROWS` rows masks the upstream gradient, sums its columns and runs
/// the products of its `PRODUCT_BLOCK_ROWS` blocks, so the masked gradient stays in cache and
/// never fills an `[n, o]` buffer. The sums are combined in block order: the same operations in
/// the same order as separate passes over fixed blocks, and the same bits for any thread count.
pub fn backward(
    x: &[f32],
    w: &[f32],
    y: &[f32],
    gy: &[f32],
    n: usize,
    o: usize,
    act: Activation,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    const { assert!(BIAS_BLOCK_ROWS.is_multiple_of(PRODUCT_BLOCK_ROWS)) };
    let i = w.len() / o.max(1);
    if o == 0 {
        // Nothing flows back: `∂x` is zero and `∂w` empty.
        return (zeroed(n * i), Vec::new(), Vec::new());
    }
    // `∂x` is written whole by its blocks' products, so its buffer is not cleared first.
    let mut gx: Vec<f32> = Vec::with_capacity(n * i);
    let blocks = n.div_ceil(BIAS_BLOCK_ROWS);
    let gx_blocks: Vec<&mut [MaybeUninit<f32>]> = if i > 0 {
        gx.spare_capacity_mut()[..n * i].chunks_mut(BIAS_BLOCK_ROWS * i).collect()
    } else {
        (0..blocks).map(|_| <&mut [MaybeUninit<f32>]>::default()).collect()
    };
    let wt = MatRef::new(w, i, o).t();
    let sums: Vec<BlockSums> = gx_blocks
        .into_par_iter()
        .enumerate()
        .with_max_len(1)
        .map(|(block, gx_block)| {
            let first = block * BIAS_BLOCK_ROWS;
            let rows = (n - first).min(BIAS_BLOCK_ROWS);
            let gy_block = &gy[first * o..(first + rows) * o];
            let gz: Cow<[f32]> = if act == Activation::Identity {
                Cow::Borrowed(gy_block)
            } else {
                let y_block = &y[first * o..(first + rows) * o];
                Cow::Owned(gy_block.iter().zip(y_block).map(|(&g, &v)| act.gradient(g, v)).collect())
            };
            let mut bias = vec![0.0f32; o];
            for row in gz.chunks_exact(o.max(1)) {
                for (a, v) in bias.iter_mut().zip(row) {
                    *a += v;
                }
            }
            let mut weight = Vec::new();
            for sub in (0..rows).step_by(PRODUCT_BLOCK_ROWS) {
                let sub_rows = (rows - sub).min(PRODUCT_BLOCK_ROWS);
                let gb = &gz[sub * o..(sub + sub_rows) * o];
                let xb = &x[(first + sub) * i..(first + sub + sub_rows) * i];
                let mut p = vec![0.0f32; i * o];
                matmul(&mut p, MatRef::new(xb, sub_rows, i).t(), MatRef::new(gb, sub_rows, o));
                weight.push(p);
                if i > 0 {
                    matmul_overwrite(&mut gx_block[sub * i..(sub + sub_rows) * i], MatRef::new(gb, sub_rows, o), wt);
                }
            }
            BlockSums { weight, bias }
        })
        .collect();
    // SAFETY: the capacity is `n · i`; the blocks cover all of it, each with products whose
    // sub-blocks cover the block's rows, and `matmul_overwrite` writes every element it is given.
    unsafe { gx.set_len(n * i) };
    let mut gw = vec![0.0f32; i * o];
    let mut gb = vec![0.0f32; o];
    for block in &sums {
        for p in &block.weight {
            for (a, v) in gw.iter_mut().zip(p) {
                *a += v;
            }
        }
        for (a, v) in gb.iter_mut().zip(&block.bias) {
            *a += v;
        }
    }
    (gx, gw, gb)
}

/// `act(x w + b)` and its gradients in f64 with plain loops: the kernels' test oracle (the
/// softplus as `ln(1 + eᶻ)`, its slope as the logistic of the pre-activation `z`).
#[cfg(test)]
pub(crate) fn reference(
    x: &[f32],
    w: &[f32],
    b: &[f32],
    gy: &[f32],
    n: usize,
    act: Activation,
) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let o = b.len();
    let i = w.len() / o;
    let mut y = vec![0.0f64; n * o];
    let mut slope = vec![1.0f64; n * o];
    for r in 0..n {
        for c in 0..o {
            let mut acc = b[c] as f64;
            for k in 0..i {
                acc += x[r * i + k] as f64 * w[k * o + c] as f64;
            }
            let j = r * o + c;
            (y[j], slope[j]) = match act {
                Activation::Identity => (acc, 1.0),
                Activation::Relu => (acc.max(0.0), if acc > 0.0 { 1.0 } else { 0.0 }),
                Activation::Softplus => (acc.exp().ln_1p(), 1.0 / (1.0 + (-acc).exp())),
            };
        }
    }
    let gz: Vec<f64> = (0..n * o).map(|j| gy[j] as f64 * slope[j]).collect();
    let mut gx = vec![0.0f64; n * i];
    let mut gw = vec![0.0f64; i * o];
    let mut gb = vec![0.0f64; o];
    for r in 0..n {
        for c in 0..o {
            let g = gz[r * o + c];
            gb[c] += g;
            for k in 0..i {
                gx[r * i + k] += g * w[k * o + c] as f64;
                gw[k * o + c] += g * x[r * i + k] as f64;
            }
        }
    }
    (y, gx, gw, gb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn close(a: &[f32], b: &[f64], tol: f64) {
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        for (x, y) in a.iter().zip(b) {
            assert!((*x as f64 - y).abs() <= tol * scale, "{x} vs {y} (scale {scale})");
        }
    }

    #[test]
    fn fused_linear_matches_the_f64_loops_for_every_activation() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // n above one bias block, odd sizes so no kernel gets an aligned shape for free.
        let (n, i, o) = (BIAS_BLOCK_ROWS + 37, 19, 13);
        let x: Vec<f32> = (0..n * i).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let w: Vec<f32> = (0..i * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let b: Vec<f32> = (0..o).map(|_| rng.random_range(-0.5f32..0.5)).collect();
        let gy: Vec<f32> = (0..n * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        for act in [Activation::Relu, Activation::Identity, Activation::Softplus] {
            let (y_ref, gx_ref, gw_ref, gb_ref) = reference(&x, &w, &b, &gy, n, act);
            let y = forward(&x, &w, &b, n, act);
            close(&y, &y_ref, 1e-5);
            if act == Activation::Relu {
                assert!(y.contains(&0.0) && y.iter().any(|&v| v > 0.0), "the ReLU must cut some");
            }
            let (gx, gw, gb) = backward(&x, &w, &y, &gy, n, o, act);
            close(&gx, &gx_ref, 1e-5);
            close(&gw, &gw_ref, 1e-5);
            close(&gb, &gb_ref, 1e-5);
        }
    }

    #[test]
    fn fused_linear_gives_the_same_bits_on_one_and_on_three_threads() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (n, i, o) = (3 * PRODUCT_BLOCK_ROWS + 11, 24, 64);
        let x: Vec<f32> = (0..n * i).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let w: Vec<f32> = (0..i * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let b: Vec<f32> = (0..o).map(|_| rng.random_range(-0.5f32..0.5)).collect();
        let gy: Vec<f32> = (0..n * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let y = forward(&x, &w, &b, n, Activation::Relu);
                let grads = backward(&x, &w, &y, &gy, n, o, Activation::Relu);
                (y, grads)
            })
        };
        assert_eq!(on(1), on(3));
    }
}
