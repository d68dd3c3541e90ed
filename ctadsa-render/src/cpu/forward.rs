//! CPU forward pass: every pixel the exact line integral of the Gaussian mixture along its ray.
//!
//! Per view: project every Gaussian and bin the footprints into bands of [`BAND`] whole image
//! rows (parallel over chunks of Gaussians; Gaussian order kept, so the result does not depend
//! on the thread count), then render the bands in parallel, each Gaussian over its footprint's
//! bounding box. Bands span the whole width so that no footprint row is cut into two pieces
//! (each rounded up to whole [`LANES`]-pixel chunks).

use multiversion::multiversion;
use rayon::prelude::*;

use super::host::HostGaussians;
use super::math::{RowEval, exp_neg};
use super::splat::{Splat, project_splats};
use crate::view_params::ViewParams;

/// Image rows per band.
pub const BAND: i32 = 16;

/// Gaussians per parallel work item.
const CHUNK: usize = 2048;

/// Projects Gaussians `first..first + out.len()` into `out`, and the band range each footprint
/// covers into `bands` (`[first, last]`, inclusive; empty for a culled Gaussian).
#[multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn project_chunk(
    g: &HostGaussians,
    first: usize,
    vp: &ViewParams,
    k_sigma: f32,
    out: &mut [Splat],
    bands: &mut [[u16; 2]],
) {
    project_splats(g, first, vp, k_sigma, out);
    for (p, b) in out.iter().zip(bands) {
        let (r0, r1) = p.row_range();
        *b = if r0 <= r1 { [r0, r1].map(|v| (v / BAND) as u16) } else { [1, 0] };
    }
}

/// Projects all Gaussians into `ws.splats` and their band ranges into `ws.ranges`, reusing
/// their memory (every slot is overwritten, so nothing is cleared first), and bins each
/// chunk's footprints by band into `ws.bins` (one [`BandBins`] per chunk of [`CHUNK`]
/// Gaussians, so binning runs in parallel).
fn project_into(g: &HostGaussians, vp: &ViewParams, k_sigma: f32, ws: &mut Workspace) {
    let n_bands = (vp.height as i32 + BAND - 1) / BAND;
    ws.splats.resize(g.len(), Splat::default());
    ws.ranges.resize(g.len(), [1, 0]);
    ws.bins.resize_with(g.len().div_ceil(CHUNK), BandBins::default);
    ws.splats
        .par_chunks_mut(CHUNK)
        .zip(ws.ranges.par_chunks_mut(CHUNK))
        .zip(ws.bins.par_iter_mut())
        .enumerate()
        .with_max_len(1)
        .for_each(|(c, ((chunk, ranges), bins))| {
            project_chunk(g, c * CHUNK, vp, k_sigma, chunk, ranges);
            bins.fill(ranges, c * CHUNK, n_bands as usize);
        });
}

/// Indices of the Gaussians of one chunk per band, in Gaussian order: band `b`'s are
/// `ids[offsets[b]..offsets[b + 1]]`.
#[derive(Default)]
struct BandBins {
    offsets: Vec<u32>,
    ids: Vec<u32>,
    /// Scratch: the next free slot of each band while filling.
    cursor: Vec<u32>,
}

impl BandBins {
    /// Bins the footprints of Gaussians `first..first + ranges.len()` by their band ranges
    /// (counting sort; deterministic), reusing this bin's memory.
    fn fill(&mut self, ranges: &[[u16; 2]], first: usize, n_bands: usize) {
        let counts = &mut self.offsets;
        counts.clear();
        counts.resize(n_bands + 1, 0);
        for &[b0, b1] in ranges {
            for b in b0..=b1 {
                counts[b as usize + 1] += 1;
            }
        }
        for b in 0..n_bands {
            counts[b + 1] += counts[b];
        }
        self.cursor.clear();
        self.cursor.extend_from_slice(&self.offsets[..n_bands]);
        // Every slot below is written: no clearing needed.
        self.ids.resize(self.offsets[n_bands] as usize, 0);
        for (i, &[b0, b1]) in ranges.iter().enumerate() {
            for b in b0..=b1 {
                self.ids[self.cursor[b as usize] as usize] = (first + i) as u32;
                self.cursor[b as usize] += 1;
            }
        }
    }

    /// The Gaussians of band `b`.
    fn band(&self, b: usize) -> &[u32] {
        &self.ids[self.offsets[b] as usize..self.offsets[b + 1] as usize]
    }
}

/// The forward pass's per-view buffers, kept between calls on the same thread ([`WORKSPACE`]):
/// the projections alone take ≈ 4 MB for 60,000 Gaussians, and allocating them afresh every call
/// cost about as much time in page faults as projecting (`perf`: ≈ 15% of the forward).
#[derive(Default)]
struct Workspace {
    splats: Vec<Splat>,
    ranges: Vec<[u16; 2]>,
    /// One per chunk of [`CHUNK`] Gaussians.
    bins: Vec<BandBins>,
}

thread_local! {
    /// This thread's forward buffers. Taken out for a call and put back after it, so a nested
    /// call on the same thread (rayon work stealing) simply starts with empty buffers. Holds the
    /// memory of the largest scene this thread rendered (≈ 75 bytes per Gaussian).
    static WORKSPACE: std::cell::Cell<Workspace> = std::cell::Cell::new(Workspace::default());
}

/// Pixels per inner-loop chunk (the lane arrays vectorise).
pub(super) const LANES: usize = 8;

/// Gaussian `p`'s line integral through the pixel at column `col` of the row `re` was made for,
/// or exactly 0 past column `last` or outside the k-σ footprint. `x_at_0` is the normalised
/// coordinate of column 0 (`−c_x / f_x`).
#[inline(always)]
fn pixel(p: &Splat, vp: &ViewParams, re: &RowEval, col: f32, x_at_0: f32, last: f32) -> f32 {
    let xn = col.mul_add(vp.inv_fx, x_at_0);
    let dx = xn - p.x0;
    let alpha = re.alpha(dx);
    let quad = re.quad(dx);
    let r2 = re.ray_len2(xn);
    let inv_a = 1.0 / alpha;
    let value = p.amp * (r2 * inv_a).sqrt() * exp_neg(-0.5 * quad * inv_a);
    let keep = (col <= last) & p.sees(quad, alpha);
    if keep { value } else { 0.0 }
}

/// Adds Gaussian `p` to two rows (`row`, `row + 1`) of a footprint at most `LANES / 2` pixels
/// wide (`c1 − c0 < LANES / 2`) with one [`LANES`]-wide vector: half the lanes per row, so
/// narrow footprints — most of them in vessel scenes — waste half as many lanes as with
/// [`splat_rows`]. Same storage as [`splat_rows`].
#[inline(always)]
fn splat_narrow_pair(p: &Splat, vp: &ViewParams, row: i32, c0: i32, c1: i32, stride: usize, out: &mut [f32]) {
    const HALF: usize = LANES / 2;
    let re = [p.row_eval(row, vp), p.row_eval(row + 1, vp)];
    // Each row coefficient as a lane array (first half row `row`, second half `row + 1`), so the
    // lane loop below compiles to full-width vectors: with a `RowEval` per half it compiled to
    // two half-width passes.
    let lanes = |f: fn(&RowEval) -> f32| -> [f32; LANES] { std::array::from_fn(|l| f(&re[l / HALF])) };
    let (a0, a1, n0, n1, r0) = (lanes(|r| r.a0), lanes(|r| r.a1), lanes(|r| r.n0), lanes(|r| r.n1), lanes(|r| r.r0));
    let (first, last) = (c0 as f32, c1 as f32);
    let x_at_0 = -vp.cx * vp.inv_fx;
    let mut v = [0.0f32; LANES];
    for (l, o) in v.iter_mut().enumerate() {
        let lane_re = RowEval { a0: a0[l], a1: a1[l], n0: n0[l], n1: n1[l], r0: r0[l], ..re[0] };
        *o = pixel(p, vp, &lane_re, first + (l % HALF) as f32, x_at_0, last);
    }
    for (r, v) in v.chunks_exact(HALF).enumerate() {
        let chunk: &mut [f32; HALF] = (&mut out[r * stride..r * stride + HALF]).try_into().expect("padded buffer");
        for (o, v) in chunk.iter_mut().zip(v) {
            *o += v;
        }
    }
}

/// Adds Gaussian `p` to the pixels of columns `[c0, c1]` of `R` consecutive image rows from
/// `row`, stored from `out[0]` (row `row`, column `c0`) with `stride` values between rows. The
/// rows are evaluated together (independent dependency chains, so the long-latency division,
/// square root and `exp` of one row overlap those of the next). Works in whole chunks of
/// [`LANES`] pixels: lanes past `c1` or outside the footprint add exactly 0, so each row of
/// `out` must extend `LANES − 1` values past `c1` (the band buffer is padded).
#[inline(always)]
fn splat_rows<const R: usize>(p: &Splat, vp: &ViewParams, row: i32, c0: i32, c1: i32, stride: usize, out: &mut [f32]) {
    let re: [RowEval; R] = std::array::from_fn(|r| p.row_eval(row + r as i32, vp));
    let n = (c1 - c0 + 1) as usize;
    // Lane arithmetic in f32 only (no integer overflow checks in the vector loop).
    let lane_col: [f32; LANES] = std::array::from_fn(|l| l as f32);
    let last = c1 as f32;
    let x_at_0 = -vp.cx * vp.inv_fx;
    let mut j = 0;
    while j < n {
        let first = (c0 as usize + j) as f32;
        let mut v = [[0.0f32; LANES]; R];
        for (re, v) in re.iter().zip(v.iter_mut()) {
            for (l, o) in v.iter_mut().enumerate() {
                *o = pixel(p, vp, re, first + lane_col[l], x_at_0, last);
            }
        }
        for (r, v) in v.iter().enumerate() {
            let start = r * stride + j;
            let chunk: &mut [f32; LANES] = (&mut out[start..start + LANES]).try_into().expect("padded buffer");
            for (o, v) in chunk.iter_mut().zip(v) {
                *o += v;
            }
        }
        j += LANES;
    }
}

/// Renders band `band` into `buf` ([`BAND`] rows of `stride` values, `stride ≥ width +
/// LANES`, so that whole chunks never run past a row).
#[multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn render_band(splats: &[Splat], ids: &[u32], vp: &ViewParams, band: i32, stride: usize, buf: &mut [f32]) {
    let y_lo = band * BAND;
    let y_hi = (y_lo + BAND - 1).min(vp.height as i32 - 1);
    for &id in ids {
        let p = &splats[id as usize];
        let (row_min, row_max) = p.row_range();
        let (r0, r1) = (row_min.max(y_lo), row_max.min(y_hi));
        let (lo, hi) = p.col_range();
        if lo > hi {
            continue;
        }
        let narrow = hi - lo < LANES as i32 / 2;
        let mut row = r0;
        while row < r1 {
            let start = (row - y_lo) as usize * stride + lo as usize;
            if narrow {
                splat_narrow_pair(p, vp, row, lo, hi, stride, &mut buf[start..]);
            } else {
                splat_rows::<2>(p, vp, row, lo, hi, stride, &mut buf[start..]);
            }
            row += 2;
        }
        if row == r1 {
            let start = (row - y_lo) as usize * stride + lo as usize;
            splat_rows::<1>(p, vp, row, lo, hi, stride, &mut buf[start..]);
        }
    }
}

/// Renders all views: output `[V, H, W]` row-major, line integrals in density × mm.
pub fn render(g: &HostGaussians, views: &[ViewParams], k_sigma: f32) -> Vec<f32> {
    let Some(first) = views.first() else { return Vec::new() };
    let (w, h) = (first.width as usize, first.height as usize);
    let mut out = vec![0.0f32; views.len() * w * h];
    for (vp, image) in views.iter().zip(out.chunks_mut(w * h)) {
        render_view(g, vp, k_sigma, image);
    }
    out
}

/// Renders one view into `image` (`H × W`, row-major).
pub fn render_view(g: &HostGaussians, vp: &ViewParams, k_sigma: f32, image: &mut [f32]) {
    let mut ws = WORKSPACE.take();
    project_into(g, vp, k_sigma, &mut ws);
    let w = vp.width as usize;
    let stride = w + LANES;
    let (splats, bins) = (&ws.splats, &ws.bins);
    image.par_chunks_mut(BAND as usize * w).enumerate().with_max_len(1).for_each(|(b, rows)| {
        let mut buf = vec![0.0f32; BAND as usize * stride];
        // Chunk by chunk, so Gaussians are added in index order (thread-count independent).
        for bins in bins {
            render_band(splats, bins.band(b), vp, b as i32, stride, &mut buf);
        }
        for (dst, src) in rows.chunks_mut(w).zip(buf.chunks(stride)) {
            dst.copy_from_slice(&src[..w]);
        }
    });
    WORKSPACE.set(ws);
}
