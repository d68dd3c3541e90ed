//! Closed mesh → solid voxels: a voxel is inside when its centre is, decided by the parity of
//! the crossings of the vertical line through the centre with the triangles (column by column).

use rayon::prelude::*;

use super::TriMesh;
use crate::data::volume::{Grid, Volume};

/// Column bins hold at most this many triangle entries (4 bytes each) in all.
const MAX_BIN_ENTRIES: usize = 1 << 27;

/// Marks (1) the voxels of `grid` whose centres lie inside the closed mesh.
pub fn voxelize_mesh(mesh: &TriMesh, grid: Grid) -> Volume<u8> {
    let mut vol = Volume::<u8>::zeros(grid);
    let [nx, ny, nz] = grid.dims;
    let h = grid.spacing_mm;
    // Each triangle's range of columns (i, j) its xy-bounding box covers (empty when outside).
    let col = |v: f64, a: usize| ((v - grid.origin_mm[a]) / h[a] - 0.5).floor();
    let ranges: Vec<Option<[usize; 4]>> = mesh
        .faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| mesh.vertices[i as usize]);
            let (i0, i1) = (col(a.x.min(b.x).min(c.x), 0), col(a.x.max(b.x).max(c.x), 0) + 1.0);
            let (j0, j1) = (col(a.y.min(b.y).min(c.y), 1), col(a.y.max(b.y).max(c.y), 1) + 1.0);
            let (i0, i1) = (i0.max(0.0), i1.min(nx as f64 - 1.0));
            let (j0, j1) = (j0.max(0.0), j1.min(ny as f64 - 1.0));
            (i1 >= i0 && j1 >= j0).then_some([i0 as usize, i1 as usize, j0 as usize, j1 as usize])
        })
        .collect();
    // Bin triangles by column, unless the bins would be too large (many triangles as wide as the
    // grid: slivers of a crafted mesh): then each column tests every triangle's range instead,
    // slower but without memory that grows with triangles × columns.
    let entries: f64 = ranges.iter().flatten().map(|r| ((r[1] - r[0] + 1) * (r[3] - r[2] + 1)) as f64).sum();
    let bins: Option<Vec<Vec<u32>>> = (entries <= MAX_BIN_ENTRIES as f64).then(|| {
        let mut bins: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        for (t, r) in ranges.iter().enumerate() {
            let Some([i0, i1, j0, j1]) = *r else { continue };
            for i in i0..=i1 {
                for j in j0..=j1 {
                    bins[i * ny + j].push(t as u32);
                }
            }
        }
        bins
    });
    vol.data.par_chunks_mut(nz).enumerate().for_each(|(column, out)| {
        let (i, j) = (column / ny, column % ny);
        let scanned: Vec<u32>;
        let tris: &[u32] = match &bins {
            Some(bins) => &bins[column],
            None => {
                scanned = (0..ranges.len() as u32)
                    .filter(|&t| {
                        ranges[t as usize]
                            .is_some_and(|[i0, i1, j0, j1]| (i0..=i1).contains(&i) && (j0..=j1).contains(&j))
                    })
                    .collect();
                &scanned
            }
        };
        if tris.is_empty() {
            return;
        }
        // A tiny fixed offset keeps the line off shared edges and vertices of the lattice.
        let x = grid.origin_mm[0] + (i as f64 + 0.5) * h[0] + 1.3e-7 * h[0];
        let y = grid.origin_mm[1] + (j as f64 + 0.5) * h[1] + 0.7e-7 * h[1];
        let mut zs: Vec<f64> = Vec::new();
        for &t in tris {
            let [a, b, c] = mesh.faces[t as usize].map(|v| mesh.vertices[v as usize]);
            // Barycentric coordinates of (x, y) in the projected triangle.
            let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
            if det.abs() < 1e-300 {
                continue;
            }
            let u = ((x - a.x) * (c.y - a.y) - (c.x - a.x) * (y - a.y)) / det;
            let v = ((b.x - a.x) * (y - a.y) - (x - a.x) * (b.y - a.y)) / det;
            if u >= 0.0 && v >= 0.0 && u + v <= 1.0 {
                zs.push(a.z + u * (b.z - a.z) + v * (c.z - a.z));
            }
        }
        zs.sort_by(f64::total_cmp);
        for pair in zs.chunks_exact(2) {
            let lo = ((pair[0] - grid.origin_mm[2]) / h[2] - 0.5).ceil().max(0.0);
            let hi = ((pair[1] - grid.origin_mm[2]) / h[2] - 0.5).floor().min(nz as f64 - 1.0);
            if lo <= hi {
                for v in &mut out[lo as usize..=hi as usize] {
                    *v = 1;
                }
            }
        }
    });
    vol
}

/// Marks the voxels of `grid` inside any connected component of `mesh`, each component
/// voxelised on its own (on the part of the grid its bounds cover) and the results joined: a
/// union of overlapping closed surfaces (a prior and the vessels joined to it) is filled where
/// [`voxelize_mesh`]'s single parity count would empty the overlaps.
pub fn voxelize_union(mesh: &TriMesh, grid: Grid) -> Volume<u8> {
    let mut out = Volume::<u8>::zeros(grid);
    let h = grid.spacing_mm;
    for part in mesh.components() {
        let Some((lo, hi)) = part.bounds_mm() else { continue };
        let range = |a: usize| {
            let first = (((lo[a] - grid.origin_mm[a]) / h[a]).floor() - 1.0).max(0.0) as usize;
            let last = ((((hi[a] - grid.origin_mm[a]) / h[a]).ceil() + 1.0).max(0.0) as usize).min(grid.dims[a]);
            (first.min(grid.dims[a]), last)
        };
        let ranges = [range(0), range(1), range(2)];
        if ranges.iter().any(|&(a, b)| a >= b) {
            continue;
        }
        let sub = Grid {
            dims: ranges.map(|(a, b)| b - a),
            spacing_mm: h,
            origin_mm: [0, 1, 2].map(|a| grid.origin_mm[a] + ranges[a].0 as f64 * h[a]),
        };
        let filled = voxelize_mesh(&part, sub);
        for k in 0..sub.dims[2] {
            for j in 0..sub.dims[1] {
                for i in 0..sub.dims[0] {
                    if filled.data[sub.index(i, j, k)] != 0 {
                        out.data[grid.index(i + ranges[0].0, j + ranges[1].0, k + ranges[2].0)] = 1;
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::mesh::marching::extract_isosurface;

    /// Thousands of triangles as wide as the grid (a crafted prior of slivers) would need
    /// triangles × columns bin entries (2.6 GB here): the column scan runs instead, with the
    /// same answer as the bins on a mesh both can take.
    #[test]
    fn grid_wide_slivers_do_not_allocate_per_column() {
        let grid = Grid { dims: [400, 400, 4], spacing_mm: [0.25; 3], origin_mm: [0.0; 3] };
        let mut mesh = TriMesh::default();
        for t in 0..1700 {
            let y = 0.05 * t as f64;
            let base = mesh.vertices.len() as u32;
            mesh.vertices.extend([
                glam::DVec3::new(0.0, y, 0.5),
                glam::DVec3::new(100.0, y + 0.01, 0.5),
                glam::DVec3::new(0.0, 100.0 - y, 0.6),
            ]);
            mesh.faces.push([base, base + 1, base + 2]);
        }
        let entries: usize = 1700 * 400 * 400;
        assert!(entries > MAX_BIN_ENTRIES, "the test exercises the scan");
        let started = std::time::Instant::now();
        let vol = voxelize_mesh(&mesh, grid);
        assert_eq!(vol.data.len(), 400 * 400 * 4);
        assert!(started.elapsed().as_secs() < 60, "{:?}", started.elapsed());
    }

    #[test]
    fn sphere_mesh_voxelizes_to_its_volume() {
        let grid = Grid { dims: [40; 3], spacing_mm: [0.5; 3], origin_mm: [-10.0; 3] };
        let mut field = Volume::<f32>::zeros(grid);
        for i in 0..40 {
            for j in 0..40 {
                for k in 0..40 {
                    field.data[grid.index(i, j, k)] = (7.0 - grid.centre_mm(i, j, k).length()) as f32;
                }
            }
        }
        let mesh = extract_isosurface(&field, 0.0);
        let fine = Grid { dims: [80; 3], spacing_mm: [0.25; 3], origin_mm: [-10.0; 3] };
        let solid = voxelize_mesh(&mesh, fine);
        let vol = solid.count_nonzero() as f64 * 0.25f64.powi(3);
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 343.0;
        assert!(((vol - exact) / exact).abs() < 0.02, "{vol} vs {exact}");
        assert_eq!(solid.get(40, 40, 40), 1);
        assert_eq!(solid.get(2, 2, 2), 0);
    }

    #[test]
    fn a_union_of_overlapping_closed_surfaces_is_filled_where_they_overlap() {
        let grid = Grid { dims: [20, 20, 20], spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
        let ball = |c: [f64; 3]| {
            let mut v = Volume::<f32>::zeros(grid);
            for k in 0..20 {
                for j in 0..20 {
                    for i in 0..20 {
                        let p = [i as f64 + 0.5 - c[0], j as f64 + 0.5 - c[1], k as f64 + 0.5 - c[2]];
                        v.data[grid.index(i, j, k)] = (5.0 - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()) as f32;
                    }
                }
            }
            extract_isosurface(&v, 0.0)
        };
        let mut both = ball([8.0, 10.0, 10.0]);
        both.append(&ball([12.0, 10.0, 10.0]));
        let centre = grid.index(10, 9, 9);
        assert_eq!(voxelize_mesh(&both, grid).data[centre], 0, "parity empties the overlap");
        assert_eq!(voxelize_union(&both, grid).data[centre], 1);
        let one = ball([8.0, 10.0, 10.0]);
        assert_eq!(voxelize_union(&one, grid).data, voxelize_mesh(&one, grid).data);
    }
}
