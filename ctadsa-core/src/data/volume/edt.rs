//! Euclidean distance transform and local thickness of a binary volume (anisotropic spacing).
//!
//! - [`squared_edt`]: exact squared distance (mm²) from each voxel centre to the nearest
//!   background voxel centre (Felzenszwalb & Huttenlocher's separable lower-envelope algorithm).
//! - [`local_thickness`]: the diameter (mm) of the largest inscribed ball that contains each
//!   voxel (Hildebrand & Rüegsegger 1997), from the balls centred on the distance ridge. The
//!   ball radius at a centre is its distance minus half a voxel (the distance runs between
//!   voxel centres), as the reference implementation's `2·(r − 0.5·h)`.

use rayon::prelude::*;

use super::Volume;

/// 1-D squared distance transform of `f` with sample spacing `h` (in place).
fn edt_1d(f: &mut [f64], h: f64, v: &mut Vec<usize>, z: &mut Vec<f64>, out: &mut Vec<f64>) {
    let n = f.len();
    v.clear();
    z.clear();
    out.clear();
    out.resize(n, 0.0);
    let pos = |q: usize| q as f64 * h;
    let mut k = 0usize;
    // Skip to the first finite sample.
    let Some(first) = f.iter().position(|x| x.is_finite()) else {
        return;
    };
    v.push(first);
    z.push(f64::NEG_INFINITY);
    z.push(f64::INFINITY);
    for q in first + 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            let s = ((f[q] + pos(q) * pos(q)) - (f[p] + pos(p) * pos(p))) / (2.0 * (pos(q) - pos(p)));
            if s <= z[k] {
                if k == 0 {
                    v[0] = q;
                    z[1] = f64::INFINITY;
                    break;
                }
                v.pop();
                z.pop();
                k -= 1;
                continue;
            }
            k += 1;
            v.push(q);
            z[k] = s;
            z.push(f64::INFINITY);
            break;
        }
    }
    let mut k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < pos(q) {
            k += 1;
        }
        let d = pos(q) - pos(v[k]);
        *o = d * d + f[v[k]];
    }
    f.copy_from_slice(out);
}

/// Squared distance (mm²) from every voxel centre to the nearest voxel with `mask == 0`;
/// 0 on the background. A volume without background gets `f64::INFINITY` everywhere.
pub fn squared_edt(mask: &Volume<u8>) -> Vec<f64> {
    let [nx, ny, nz] = mask.grid.dims;
    let h = mask.grid.spacing_mm;
    let mut d: Vec<f64> = mask.data.iter().map(|&m| if m == 0 { 0.0 } else { f64::INFINITY }).collect();
    // Along z (contiguous).
    d.par_chunks_mut(nz)
        .for_each_init(|| (Vec::new(), Vec::new(), Vec::new()), |(v, z, o), line| edt_1d(line, h[2], v, z, o));
    // Along y, then x: gather lines, transform, scatter.
    let axis_pass = |d: &mut Vec<f64>, axis: usize| {
        let (n_axis, stride) = if axis == 1 { (ny, nz) } else { (nx, ny * nz) };
        let lines: Vec<usize> = (0..nx * ny * nz).filter(|&idx| (idx / stride) % n_axis == 0).collect();
        let results: Vec<Vec<f64>> = lines
            .par_iter()
            .map_init(
                || (Vec::new(), Vec::new(), Vec::new()),
                |(v, z, o), &start| {
                    let mut line: Vec<f64> = (0..n_axis).map(|t| d[start + t * stride]).collect();
                    edt_1d(&mut line, h[axis], v, z, o);
                    line
                },
            )
            .collect();
        for (start, line) in lines.iter().zip(results) {
            for (t, val) in line.into_iter().enumerate() {
                d[start + t * stride] = val;
            }
        }
    };
    axis_pass(&mut d, 1);
    axis_pass(&mut d, 0);
    d
}

/// Local thickness (mm) of the foreground of `mask`; 0 on the background.
pub fn local_thickness(mask: &Volume<u8>) -> Vec<f64> {
    let g = mask.grid;
    let [nx, ny, nz] = g.dims;
    let h = g.spacing_mm;
    let half_voxel = 0.5 * h.iter().copied().fold(f64::INFINITY, f64::min);
    let dist: Vec<f64> = squared_edt(mask).into_iter().map(f64::sqrt).collect();
    // Ridge: foreground voxels whose distance is not exceeded by any 26-neighbour.
    let ridge: Vec<usize> = (0..g.len())
        .into_par_iter()
        .filter(|&idx| {
            let r = dist[idx];
            if !(r > 0.0) {
                return false;
            }
            let (i, j, k) = (idx / (ny * nz), (idx / nz) % ny, idx % nz);
            for di in -1i64..=1 {
                for dj in -1i64..=1 {
                    for dk in -1i64..=1 {
                        let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                        if a < 0 || b < 0 || c < 0 || a >= nx as i64 || b >= ny as i64 || c >= nz as i64 {
                            continue;
                        }
                        if dist[g.index(a as usize, b as usize, c as usize)] > r {
                            return false;
                        }
                    }
                }
            }
            true
        })
        .collect();
    // Each ridge ball paints its diameter onto the voxels it contains (max over balls).
    let mut thick = vec![0.0f64; g.len()];
    let mut balls: Vec<(usize, f64)> = ridge.iter().map(|&idx| (idx, (dist[idx] - half_voxel).max(0.0))).collect();
    balls.sort_by(|a, b| a.1.total_cmp(&b.1));
    for (idx, r) in balls {
        let (i, j, k) = (idx / (ny * nz), (idx / nz) % ny, idx % nz);
        let diameter = 2.0 * r;
        let reach = [0, 1, 2].map(|a| (dist[idx] / h[a]).ceil() as i64);
        let r_paint = dist[idx];
        for di in -reach[0]..=reach[0] {
            for dj in -reach[1]..=reach[1] {
                for dk in -reach[2]..=reach[2] {
                    let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                    if a < 0 || b < 0 || c < 0 || a >= nx as i64 || b >= ny as i64 || c >= nz as i64 {
                        continue;
                    }
                    let d2 = (di as f64 * h[0]).powi(2) + (dj as f64 * h[1]).powi(2) + (dk as f64 * h[2]).powi(2);
                    if d2 < r_paint * r_paint {
                        let t = g.index(a as usize, b as usize, c as usize);
                        if mask.data[t] != 0 && thick[t] < diameter {
                            thick[t] = diameter;
                        }
                    }
                }
            }
        }
    }
    thick
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::volume::Grid;

    fn brute(mask: &Volume<u8>) -> Vec<f64> {
        let g = mask.grid;
        let bg: Vec<glam::DVec3> = (0..g.len())
            .filter(|&i| mask.data[i] == 0)
            .map(|idx| g.centre_mm(idx / (g.dims[1] * g.dims[2]), (idx / g.dims[2]) % g.dims[1], idx % g.dims[2]))
            .collect();
        (0..g.len())
            .map(|idx| {
                let p = g.centre_mm(idx / (g.dims[1] * g.dims[2]), (idx / g.dims[2]) % g.dims[1], idx % g.dims[2]);
                bg.iter().map(|b| (*b - p).length_squared()).fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    #[test]
    fn edt_matches_brute_force_anisotropic() {
        let grid = Grid { dims: [9, 7, 11], spacing_mm: [0.5, 0.7, 0.3], origin_mm: [0.0; 3] };
        let mut mask = Volume::<u8>::zeros(grid);
        let mut s = 12345u64;
        for v in &mut mask.data {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            *v = !(s >> 33).is_multiple_of(5) as u8;
        }
        let fast = squared_edt(&mask);
        let slow = brute(&mask);
        for (a, b) in fast.iter().zip(&slow) {
            assert!((a - b).abs() < 1e-9, "{a} vs {b}");
        }
    }

    #[test]
    fn thickness_of_a_cylinder_is_its_diameter() {
        let grid = Grid { dims: [40, 40, 10], spacing_mm: [0.25; 3], origin_mm: [-5.125, -5.125, -1.25] };
        let mut mask = Volume::<u8>::zeros(grid);
        for i in 0..40 {
            for j in 0..40 {
                for k in 0..10 {
                    let p = grid.centre_mm(i, j, k);
                    mask.data[grid.index(i, j, k)] = (p.x * p.x + p.y * p.y <= 2.0 * 2.0) as u8;
                }
            }
        }
        // Make it a long tube: thickness along z is unbounded, so the ridge is the axis.
        let t = local_thickness(&mask);
        let centre = t[grid.index(20, 20, 5)];
        assert!((centre - 4.0).abs() < 0.3, "thickness at the axis {centre} mm, expected ≈ 4");
    }
}
