//! CPU kernels of the fused linear layer on host slices, row-major: matrix products through
//! ndarray's `general_mat_mul` (matrixmultiply; transposed operands are strided views, never
//! copies), bias and ReLU in the same pass.

use ndarray::linalg::general_mat_mul;
use ndarray::{ArrayView2, ArrayViewMut2};
use rayon::prelude::*;

/// Rows per block of the bias-gradient sum (fixed, so the sum is the same for any thread count).
const BIAS_BLOCK_ROWS: usize = 4096;

fn view2(values: &[f32], rows: usize, cols: usize) -> ArrayView2<'_, f32> {
    ArrayView2::from_shape((rows, cols), values).expect("the op checked the shapes")
}

/// `y = act(x w + b)` for `x` `[n, i]`, `w` `[i, o]`, `b` `[o]`: `[n, o]`.
pub fn forward(x: &[f32], w: &[f32], b: &[f32], n: usize, relu: bool) -> Vec<f32> {
    let o = b.len();
    let i = w.len() / o.max(1);
    let mut y: Vec<f32> = Vec::with_capacity(n * o);
    for _ in 0..n {
        y.extend_from_slice(b);
    }
    {
        let mut yv = ArrayViewMut2::from_shape((n, o), &mut y[..]).expect("n · o values");
        general_mat_mul(1.0, &view2(x, n, i), &view2(w, i, o), 1.0, &mut yv);
    }
    if relu {
        y.par_chunks_mut(1 << 14).for_each(|c| c.iter_mut().for_each(|v| *v = v.max(0.0)));
    }
    y
}

/// Gradients of the fused layer for the upstream gradient `gy` `[n, o]`, given the input `x`
/// `[n, i]`, weight `w` `[i, o]` and the forward output `y` (its sign masks the ReLU):
/// `(∂x [n, i], ∂w [i, o], ∂b [o])`.
pub fn backward(
    x: &[f32],
    w: &[f32],
    y: &[f32],
    gy: &[f32],
    n: usize,
    o: usize,
    relu: bool,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let i = w.len() / o.max(1);
    let gz: Vec<f32> = if relu {
        gy.par_iter().zip(y.par_iter()).map(|(&g, &v)| if v > 0.0 { g } else { 0.0 }).collect()
    } else {
        gy.to_vec()
    };
    let gzv = view2(&gz, n, o);
    let mut gw = vec![0.0f32; i * o];
    general_mat_mul(
        1.0,
        &view2(x, n, i).t(),
        &gzv,
        0.0,
        &mut ArrayViewMut2::from_shape((i, o), &mut gw[..]).expect("i · o values"),
    );
    let mut gx = vec![0.0f32; n * i];
    general_mat_mul(
        1.0,
        &gzv,
        &view2(w, i, o).t(),
        0.0,
        &mut ArrayViewMut2::from_shape((n, i), &mut gx[..]).expect("n · i values"),
    );
    (gx, gw, column_sums(&gz, o))
}

/// Σ over rows of a row-major `[n, o]` matrix, in fixed row blocks summed in order.
fn column_sums(m: &[f32], o: usize) -> Vec<f32> {
    if o == 0 {
        return Vec::new();
    }
    let partial: Vec<Vec<f32>> = m
        .par_chunks(BIAS_BLOCK_ROWS * o)
        .map(|block| {
            let mut s = vec![0.0f32; o];
            for row in block.chunks_exact(o) {
                for (a, v) in s.iter_mut().zip(row) {
                    *a += v;
                }
            }
            s
        })
        .collect();
    let mut sums = vec![0.0f32; o];
    for p in &partial {
        for (a, v) in sums.iter_mut().zip(p) {
            *a += v;
        }
    }
    sums
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
}
