//! CPU kernels of the fused linear layer on host slices, row-major: matrix products through
//! the `gemm` crate (transposed operands are strided views, never copies) on fixed row blocks in
//! parallel, bias and ReLU in the same pass. The blocks do not depend on the thread count, and
//! the weight gradient sums its per-block products in block order, so results are the same for
//! any number of threads.

use std::borrow::Cow;

use rayon::prelude::*;

use crate::method::par_buffer::{repeated_rows, zeroed};

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

/// `dst = a · b` (`dst += a · b` when `accumulate`), `dst` row-major `[a.rows, b.cols]`, on the
/// calling thread.
///
/// Panics when the shapes do not match or a view reaches outside its slice (the callers pass
/// the op's checked shapes).
fn matmul(dst: &mut [f32], a: MatRef, b: MatRef, accumulate: bool) {
    let (m, k, n) = (a.rows, a.cols, b.cols);
    assert!(
        b.rows == k && dst.len() == m * n && a.in_bounds() && b.in_bounds(),
        "matmul: [{m}, {k}] · [{}, {n}] into {} values",
        b.rows,
        dst.len()
    );
    if m == 0 || n == 0 {
        return;
    }
    // SAFETY: the assertion bounds every element gemm reads (`a`, `b`: in_bounds) and writes
    // (`dst`: m rows of n contiguous values); `dst` is borrowed mutably, so it aliases neither.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
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
/// product and ReLU run in one task, while the block is in cache.
pub fn forward(x: &[f32], w: &[f32], b: &[f32], n: usize, relu: bool) -> Vec<f32> {
    let o = b.len();
    let i = w.len() / o.max(1);
    let mut y = repeated_rows(b, n);
    let wm = MatRef::new(w, i, o);
    y.par_chunks_mut(PRODUCT_BLOCK_ROWS * o.max(1)).enumerate().with_max_len(1).for_each(|(block, d)| {
        let rows = d.len() / o.max(1);
        if i > 0 {
            let first = block * PRODUCT_BLOCK_ROWS;
            matmul(d, MatRef::new(&x[first * i..(first + rows) * i], rows, i), wm, true);
        }
        if relu {
            d.iter_mut().for_each(|v| *v = v.max(0.0));
        }
    });
    y
}

/// What one task of [`backward`] sums over its rows: the weight gradient's product per
/// [`PRODUCT_BLOCK_ROWS`] block, in block order, and the bias gradient's column sums.
struct BlockSums {
    weight: Vec<Vec<f32>>,
    bias: Vec<f32>,
}

/// Gradients of the fused layer for the upstream gradient `gy` `[n, o]`, given the input `x`
/// `[n, i]`, weight `w` `[i, o]` and the forward output `y` (its sign masks the ReLU):
/// `(∂x [n, i], ∂w [i, o], ∂b [o])`.
///
/// One task per [`BIAS_BLOCK_ROWS`] rows masks the upstream gradient, sums its columns and runs
/// the products of its [`PRODUCT_BLOCK_ROWS`] blocks, so the masked gradient stays in cache and
/// never fills an `[n, o]` buffer. The sums are combined in block order: the same operations in
/// the same order as separate passes over fixed blocks, and the same bits for any thread count.
pub fn backward(
    x: &[f32],
    w: &[f32],
    y: &[f32],
    gy: &[f32],
    n: usize,
    o: usize,
    relu: bool,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    const { assert!(BIAS_BLOCK_ROWS.is_multiple_of(PRODUCT_BLOCK_ROWS)) };
    let i = w.len() / o.max(1);
    let mut gx = zeroed(n * i);
    let blocks = n.div_ceil(BIAS_BLOCK_ROWS);
    let gx_blocks: Vec<&mut [f32]> = if i > 0 {
        gx.chunks_mut(BIAS_BLOCK_ROWS * i).collect()
    } else {
        (0..blocks).map(|_| <&mut [f32]>::default()).collect()
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
            let gz: Cow<[f32]> = if relu {
                let y_block = &y[first * o..(first + rows) * o];
                Cow::Owned(gy_block.iter().zip(y_block).map(|(&g, &v)| if v > 0.0 { g } else { 0.0 }).collect())
            } else {
                Cow::Borrowed(gy_block)
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
                matmul(&mut p, MatRef::new(xb, sub_rows, i).t(), MatRef::new(gb, sub_rows, o), false);
                weight.push(p);
                if i > 0 && o > 0 {
                    matmul(&mut gx_block[sub * i..(sub + sub_rows) * i], MatRef::new(gb, sub_rows, o), wt, false);
                }
            }
            BlockSums { weight, bias }
        })
        .collect();
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

/// `x w + b` and its gradients in f64 with plain loops: the kernels' test oracle.
#[cfg(test)]
pub(crate) fn reference(
    x: &[f32],
    w: &[f32],
    b: &[f32],
    gy: &[f32],
    n: usize,
    relu: bool,
) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let o = b.len();
    let i = w.len() / o;
    let mut y = vec![0.0f64; n * o];
    for r in 0..n {
        for c in 0..o {
            let mut acc = b[c] as f64;
            for k in 0..i {
                acc += x[r * i + k] as f64 * w[k * o + c] as f64;
            }
            y[r * o + c] = if relu { acc.max(0.0) } else { acc };
        }
    }
    let gz: Vec<f64> = (0..n * o).map(|j| if !relu || y[j] > 0.0 { gy[j] as f64 } else { 0.0 }).collect();
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
    fn fused_linear_matches_the_f64_loops_with_and_without_relu() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // n above one bias block, odd sizes so no kernel gets an aligned shape for free.
        let (n, i, o) = (BIAS_BLOCK_ROWS + 37, 19, 13);
        let x: Vec<f32> = (0..n * i).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let w: Vec<f32> = (0..i * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let b: Vec<f32> = (0..o).map(|_| rng.random_range(-0.5f32..0.5)).collect();
        let gy: Vec<f32> = (0..n * o).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        for relu in [true, false] {
            let (y_ref, gx_ref, gw_ref, gb_ref) = reference(&x, &w, &b, &gy, n, relu);
            let y = forward(&x, &w, &b, n, relu);
            close(&y, &y_ref, 1e-5);
            if relu {
                assert!(y.contains(&0.0) && y.iter().any(|&v| v > 0.0), "the ReLU must cut some");
            }
            let (gx, gw, gb) = backward(&x, &w, &y, &gy, n, o, relu);
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
                let y = forward(&x, &w, &b, n, true);
                let grads = backward(&x, &w, &y, &gy, n, o, true);
                (y, grads)
            })
        };
        assert_eq!(on(1), on(3));
    }
}
