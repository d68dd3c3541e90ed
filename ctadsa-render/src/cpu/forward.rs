//! CPU forward pass: every pixel the exact line integral of the Gaussian mixture along its ray.
//!
//! Per view: project every Gaussian (parallel), bin the footprints into square tiles (Gaussian
//! order kept, so the result does not depend on the thread count), then render the tiles in
//! parallel, each Gaussian only over the exact per-row span of its footprint.

use multiversion::multiversion;
use rayon::prelude::*;

use super::host::HostGaussians;
use super::math::{Projected, RowEval, exp_neg};
use super::project::project_range;
use crate::view_params::ViewParams;

/// Tile edge in pixels.
pub const TILE: i32 = 32;

/// Gaussians per parallel work item.
const CHUNK: usize = 2048;

/// Projects Gaussians `first..first + out.len()` into `out`, and the tile range each footprint
/// covers into `tiles` (`[tx0, tx1, ty0, ty1]`, inclusive; empty for a culled Gaussian).
#[multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn project_chunk(
    g: &HostGaussians,
    first: usize,
    vp: &ViewParams,
    k_sigma: f32,
    out: &mut [Option<Projected>],
    tiles: &mut [[u16; 4]],
) {
    project_range(g, first, vp, k_sigma, out, None);
    for (p, t) in out.iter().zip(tiles) {
        *t = match p {
            Some(p) => [p.col_min, p.col_max, p.row_min, p.row_max].map(|v| (v / TILE) as u16),
            None => [1, 0, 1, 0],
        };
    }
}

/// Projects all Gaussians into one view (`None` = culled), with their tile ranges.
pub fn project_all(g: &HostGaussians, vp: &ViewParams, k_sigma: f32) -> (Vec<Option<Projected>>, Vec<[u16; 4]>) {
    let mut out = vec![None; g.len()];
    let mut tiles = vec![[0u16; 4]; g.len()];
    out.par_chunks_mut(CHUNK)
        .zip(tiles.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, (chunk, tiles))| project_chunk(g, c * CHUNK, vp, k_sigma, chunk, tiles));
    (out, tiles)
}

/// Gaussian indices per tile, in Gaussian order: `ids[offsets[t]..offsets[t + 1]]`.
pub struct TileBins {
    pub tiles_x: i32,
    pub tiles_y: i32,
    pub offsets: Vec<u32>,
    pub ids: Vec<u32>,
}

/// Bins footprints by their tile ranges (counting sort; deterministic).
pub fn bin_tiles(ranges: &[[u16; 4]], vp: &ViewParams) -> TileBins {
    let tiles_x = (vp.width as i32 + TILE - 1) / TILE;
    let tiles_y = (vp.height as i32 + TILE - 1) / TILE;
    let n_tiles = (tiles_x * tiles_y) as usize;
    let mut counts = vec![0u32; n_tiles + 1];
    let row_len = tiles_x as usize;
    for &[tx0, tx1, ty0, ty1] in ranges {
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                counts[ty as usize * row_len + tx as usize + 1] += 1;
            }
        }
    }
    for t in 0..n_tiles {
        counts[t + 1] += counts[t];
    }
    let offsets = counts;
    let mut fill = offsets.clone();
    let mut ids = vec![0u32; offsets[n_tiles] as usize];
    for (i, &[tx0, tx1, ty0, ty1]) in ranges.iter().enumerate() {
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                let t = ty as usize * row_len + tx as usize;
                ids[fill[t] as usize] = i as u32;
                fill[t] += 1;
            }
        }
    }
    TileBins { tiles_x, tiles_y, offsets, ids }
}

/// Pixels per inner-loop chunk (the lane arrays vectorise).
const LANES: usize = 8;

/// Adds Gaussian `p` to the pixels of columns `[c0, c1]` of `R` consecutive image rows from
/// `row`, stored from `out[0]` (row `row`, column `c0`) with `stride` values between rows. The
/// rows are evaluated together (independent dependency chains, so the long-latency division,
/// square root and `exp` of one row overlap those of the next). Works in whole chunks of
/// [`LANES`] pixels: lanes past `c1` or outside the footprint add exactly 0, so each row of
/// `out` must extend `LANES − 1` values past `c1` (the tile buffer is padded).
#[inline(always)]
fn splat_rows<const R: usize>(
    p: &Projected,
    vp: &ViewParams,
    row: i32,
    c0: i32,
    c1: i32,
    stride: usize,
    out: &mut [f32],
) {
    let re: [RowEval; R] = std::array::from_fn(|r| p.row_eval(row + r as i32, vp));
    let n = (c1 - c0 + 1) as usize;
    // Lane arithmetic in f32 only (no integer overflow checks in the vector loop).
    let lane_col: [f32; LANES] = std::array::from_fn(|l| l as f32);
    let last = c1 as f32;
    let mut j = 0;
    while j < n {
        let first = (c0 as usize + j) as f32;
        let mut v = [[0.0f32; LANES]; R];
        for (re, v) in re.iter().zip(v.iter_mut()) {
            for (l, o) in v.iter_mut().enumerate() {
                let col = first + lane_col[l];
                let dx = (col - p.u0) * vp.inv_fx;
                let alpha = re.alpha(dx);
                let quad = re.quad(dx);
                let xn = p.x0 + dx;
                let r2 = re.ray_len2(xn);
                let inv_a = 1.0 / alpha;
                let value = p.amp * (r2 * inv_a).sqrt() * exp_neg(-0.5 * quad * inv_a);
                let keep = (col <= last) & p.sees(quad, alpha);
                *o = if keep { value } else { 0.0 };
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

/// Renders one tile into `buf` (`TILE × TILE` row-major, plus [`LANES`] padding).
#[multiversion(targets("x86_64+avx2+fma+sse4.1", "x86_64+sse4.1"))]
fn render_tile(projected: &[Option<Projected>], ids: &[u32], vp: &ViewParams, tx: i32, ty: i32, buf: &mut [f32]) {
    let (x_lo, y_lo) = (tx * TILE, ty * TILE);
    let x_hi = (x_lo + TILE - 1).min(vp.width as i32 - 1);
    let y_hi = (y_lo + TILE - 1).min(vp.height as i32 - 1);
    for &id in ids {
        let Some(p) = &projected[id as usize] else { continue };
        let r0 = p.row_min.max(y_lo);
        let r1 = p.row_max.min(y_hi);
        let lo = p.col_min.max(x_lo);
        let hi = p.col_max.min(x_hi);
        if lo > hi {
            continue;
        }
        let stride = TILE as usize;
        let mut row = r0;
        while row < r1 {
            let start = ((row - y_lo) * TILE + (lo - x_lo)) as usize;
            splat_rows::<2>(p, vp, row, lo, hi, stride, &mut buf[start..]);
            row += 2;
        }
        if row == r1 {
            let start = ((row - y_lo) * TILE + (lo - x_lo)) as usize;
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
    let (projected, ranges) = project_all(g, vp, k_sigma);
    let bins = bin_tiles(&ranges, vp);
    let tiles: Vec<(i32, i32)> = (0..bins.tiles_y).flat_map(|ty| (0..bins.tiles_x).map(move |tx| (tx, ty))).collect();
    let rendered: Vec<Vec<f32>> = tiles
        .par_iter()
        .map(|&(tx, ty)| {
            let t = (ty * bins.tiles_x + tx) as usize;
            let ids = &bins.ids[bins.offsets[t] as usize..bins.offsets[t + 1] as usize];
            let mut buf = vec![0.0f32; (TILE * TILE) as usize + LANES];
            render_tile(&projected, ids, vp, tx, ty, &mut buf);
            buf
        })
        .collect();
    let w = vp.width as usize;
    for (&(tx, ty), buf) in tiles.iter().zip(&rendered) {
        let x_lo = (tx * TILE) as usize;
        let cols = (w - x_lo).min(TILE as usize);
        for r in 0..TILE as usize {
            let row = ty as usize * TILE as usize + r;
            if row >= vp.height as usize {
                break;
            }
            let dst = &mut image[row * w + x_lo..row * w + x_lo + cols];
            dst.copy_from_slice(&buf[r * TILE as usize..r * TILE as usize + cols]);
        }
    }
}

/// Number of (pixel, Gaussian) pairs that contribute (pixels whose ray meets the k-σ
/// ellipsoid), for throughput figures.
pub fn count_pairs(g: &HostGaussians, views: &[ViewParams], k_sigma: f32) -> u64 {
    views
        .iter()
        .map(|vp| {
            project_all(g, vp, k_sigma)
                .0
                .par_iter()
                .flatten()
                .map(|p| {
                    let mut count = 0u64;
                    for row in p.row_min..=p.row_max {
                        let re = p.row_eval(row, vp);
                        for col in p.col_min..=p.col_max {
                            let dx = (col as f32 - p.u0) * vp.inv_fx;
                            let alpha = re.alpha(dx);
                            let quad = re.quad(dx);
                            count += p.sees(quad, alpha) as u64;
                        }
                    }
                    count
                })
                .sum::<u64>()
        })
        .sum()
}

/// Number of pixel lanes the forward kernel evaluates (footprint boxes clipped to tiles, rows
/// rounded up to whole [`LANES`]-pixel chunks), for throughput figures: the ratio to
/// [`count_pairs`] is the share of the vector work spent outside footprints.
pub fn count_lanes(g: &HostGaussians, views: &[ViewParams], k_sigma: f32) -> u64 {
    views
        .iter()
        .map(|vp| {
            project_all(g, vp, k_sigma)
                .0
                .par_iter()
                .flatten()
                .map(|p| {
                    let mut lanes = 0u64;
                    for tx in p.col_min / TILE..=p.col_max / TILE {
                        let width = (p.col_max.min(tx * TILE + TILE - 1) - p.col_min.max(tx * TILE) + 1) as u64;
                        lanes += width.div_ceil(LANES as u64) * LANES as u64;
                    }
                    lanes * (p.row_max - p.row_min + 1) as u64
                })
                .sum::<u64>()
        })
        .sum()
}
