//! Closed mesh → solid voxels: a voxel is inside when its centre is, decided by the parity of
//! the crossings of the vertical line through the centre with the triangles (column by column).

use rayon::prelude::*;

use super::TriMesh;
use crate::data::volume::{Grid, Volume};

/// Marks (1) the voxels of `grid` whose centres lie inside the closed mesh.
pub fn voxelize_mesh(mesh: &TriMesh, grid: Grid) -> Volume<u8> {
    let mut vol = Volume::<u8>::zeros(grid);
    let [nx, ny, nz] = grid.dims;
    let h = grid.spacing_mm;
    // Bin triangles by the columns (i, j) their xy-bounding box covers.
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
    let col = |v: f64, a: usize| ((v - grid.origin_mm[a]) / h[a] - 0.5).floor();
    for (t, f) in mesh.faces.iter().enumerate() {
        let [a, b, c] = f.map(|i| mesh.vertices[i as usize]);
        let (i0, i1) = (col(a.x.min(b.x).min(c.x), 0), col(a.x.max(b.x).max(c.x), 0) + 1.0);
        let (j0, j1) = (col(a.y.min(b.y).min(c.y), 1), col(a.y.max(b.y).max(c.y), 1) + 1.0);
        let (i0, i1) = (i0.max(0.0) as usize, (i1.min(nx as f64 - 1.0)).max(-1.0));
        let (j0, j1) = (j0.max(0.0) as usize, (j1.min(ny as f64 - 1.0)).max(-1.0));
        if i1 < 0.0 || j1 < 0.0 {
            continue;
        }
        for i in i0..=i1 as usize {
            for j in j0..=j1 as usize {
                bins[i * ny + j].push(t as u32);
            }
        }
    }
    vol.data.par_chunks_mut(nz).enumerate().for_each(|(column, out)| {
        let (i, j) = (column / ny, column % ny);
        let tris = &bins[column];
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::mesh::marching::extract_isosurface;

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
}
