//! CPU kernel of the separable 11-tap blur of `[V, H, W]` images with zero padding: along the
//! rows, then along the columns, one task per image row. Each output sums its taps in tap order.

use rayon::prelude::*;

/// Half-width of the window (11 taps).
pub const RADIUS: usize = 5;

/// Blurs `x` (`[V, H, W]` row-major) with `taps` along W, then H.
pub fn blur(x: &[f32], v: usize, h: usize, w: usize, taps: &[f32; 2 * RADIUS + 1]) -> Vec<f32> {
    debug_assert_eq!(x.len(), v * h * w);
    if x.is_empty() {
        return Vec::new();
    }
    let mut along_w = vec![0.0f32; x.len()];
    along_w.par_chunks_mut(w).zip(x.par_chunks(w)).for_each(|(out, row)| {
        // Tap by tap over the whole row (vectorised), each output still summing its taps in
        // tap order: output `c` takes `row[c + k − RADIUS]` where that lies in the row.
        for (k, t) in taps.iter().enumerate() {
            let lo = RADIUS.saturating_sub(k);
            let hi = (w + RADIUS).saturating_sub(k).min(w);
            if lo < hi {
                let from = lo + k - RADIUS;
                for (o, s) in out[lo..hi].iter_mut().zip(&row[from..from + (hi - lo)]) {
                    *o += t * s;
                }
            }
        }
    });
    let mut out = vec![0.0f32; x.len()];
    out.par_chunks_mut(w).enumerate().for_each(|(vr, o)| {
        let (img, r) = (vr / h, vr % h);
        let plane = &along_w[img * h * w..(img + 1) * h * w];
        for (k, t) in taps.iter().enumerate() {
            if let Some(rr) = (r + k).checked_sub(RADIUS).filter(|&rr| rr < h) {
                for (a, s) in o.iter_mut().zip(&plane[rr * w..(rr + 1) * w]) {
                    *a += t * s;
                }
            }
        }
    });
    out
}
