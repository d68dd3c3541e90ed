//! Iso-surface extraction by marching tetrahedra on the Kuhn (Freudenthal) split of each voxel
//! cube into six tetrahedra around its main diagonal. Neighbouring cubes split their shared faces
//! the same way and vertices are shared by grid edge, so the surface of a volume padded with an
//! outside border is closed (every edge has exactly two triangles), which plain marching-cubes
//! tables do not guarantee in their ambiguous cases.
//!
//! Values sit at voxel centres; a voxel is inside when its value is `> level`. Vertices are
//! placed by linear interpolation along grid edges and mapped to world mm by the volume's
//! index-to-world matrix. Triangles face outwards (towards lower values).

use std::collections::HashMap;

use glam::DVec3;

use super::TriMesh;
use crate::data::volume::Volume;

/// Corner offsets of a cube, indexed by the bits `x | y << 1 | z << 2`.
const CORNER: [[usize; 3]; 8] =
    [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1], [1, 1, 1]];

/// The six tetrahedra of the Kuhn split: paths 0 → 7 adding one axis bit at a time.
const TETS: [[usize; 4]; 6] = [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]];

/// Extracts the surface `{value = level}` of `volume`. The volume is padded by one voxel of
/// `min(smallest value, level)` (outside), so the surface closes at the volume border.
pub fn extract_isosurface(volume: &Volume<f32>, level: f32) -> TriMesh {
    let [nx, ny, nz] = volume.grid.dims;
    let pad = volume.data.iter().copied().fold(level, f32::min);
    // Padded sample: index in [-1, n].
    let value = |i: i64, j: i64, k: i64| -> f32 {
        if i < 0 || j < 0 || k < 0 || i >= nx as i64 || j >= ny as i64 || k >= nz as i64 {
            pad
        } else {
            volume.data[volume.grid.index(i as usize, j as usize, k as usize)]
        }
    };
    let key = |i: i64, j: i64, k: i64| -> u64 {
        (((i + 1) as u64) * (ny as u64 + 2) + (j + 1) as u64) * (nz as u64 + 2) + (k + 1) as u64
    };
    let to_world = |p: DVec3| volume.index_to_world.transform_point3(p);
    let mut mesh = TriMesh::default();
    let mut cache: HashMap<(u64, u64), u32> = HashMap::new();
    for i in -1..nx as i64 {
        for j in -1..ny as i64 {
            for k in -1..nz as i64 {
                let mut vals = [0.0f32; 8];
                let mut inside_count = 0;
                for (c, off) in CORNER.iter().enumerate() {
                    vals[c] = value(i + off[0] as i64, j + off[1] as i64, k + off[2] as i64);
                    inside_count += (vals[c] > level) as usize;
                }
                if inside_count == 0 || inside_count == 8 {
                    continue;
                }
                let pos = |c: usize| {
                    DVec3::new(
                        (i + CORNER[c][0] as i64) as f64,
                        (j + CORNER[c][1] as i64) as f64,
                        (k + CORNER[c][2] as i64) as f64,
                    )
                };
                let ckey = |c: usize| key(i + CORNER[c][0] as i64, j + CORNER[c][1] as i64, k + CORNER[c][2] as i64);
                let mut vertex = |a: usize, b: usize, mesh: &mut TriMesh| -> u32 {
                    let (ka, kb) = (ckey(a), ckey(b));
                    let edge = (ka.min(kb), ka.max(kb));
                    *cache.entry(edge).or_insert_with(|| {
                        let (va, vb) = (vals[a] as f64, vals[b] as f64);
                        // One end is inside (> level), the other not, so vb ≠ va.
                        let t = ((level as f64 - va) / (vb - va)).clamp(0.0, 1.0);
                        let p = pos(a) + t * (pos(b) - pos(a));
                        mesh.vertices.push(to_world(p));
                        mesh.vertices.len() as u32 - 1
                    })
                };
                for tet in TETS {
                    let ins: Vec<usize> = tet.iter().copied().filter(|&c| vals[c] > level).collect();
                    let outs: Vec<usize> = tet.iter().copied().filter(|&c| vals[c] <= level).collect();
                    let tris: Vec<[u32; 3]> = match ins.len() {
                        1 => vec![[
                            vertex(ins[0], outs[0], &mut mesh),
                            vertex(ins[0], outs[1], &mut mesh),
                            vertex(ins[0], outs[2], &mut mesh),
                        ]],
                        3 => vec![[
                            vertex(outs[0], ins[0], &mut mesh),
                            vertex(outs[0], ins[1], &mut mesh),
                            vertex(outs[0], ins[2], &mut mesh),
                        ]],
                        2 => {
                            let a = vertex(ins[0], outs[0], &mut mesh);
                            let b = vertex(ins[0], outs[1], &mut mesh);
                            let c = vertex(ins[1], outs[1], &mut mesh);
                            let d = vertex(ins[1], outs[0], &mut mesh);
                            vec![[a, b, c], [a, c, d]]
                        }
                        _ => continue,
                    };
                    // Orient outwards: the normal should point from the inside corners to the outside ones.
                    let centre = |cs: &[usize]| cs.iter().map(|&c| pos(c)).sum::<DVec3>() / cs.len() as f64;
                    let outward = to_world(centre(&outs)) - to_world(centre(&ins));
                    for mut t in tris {
                        let [p0, p1, p2] = t.map(|v| mesh.vertices[v as usize]);
                        if (p1 - p0).cross(p2 - p0).dot(outward) < 0.0 {
                            t.swap(1, 2);
                        }
                        mesh.faces.push(t);
                    }
                }
            }
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::volume::Grid;

    fn sphere(radius: f64, h: f64, n: usize) -> Volume<f32> {
        let grid = Grid { dims: [n, n, n], spacing_mm: [h; 3], origin_mm: [-(n as f64) * h / 2.0; 3] };
        let mut v = Volume::<f32>::zeros(grid);
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = grid.centre_mm(i, j, k);
                    v.data[grid.index(i, j, k)] = (radius - p.length()) as f32;
                }
            }
        }
        v
    }

    #[test]
    fn sphere_surface_is_closed_and_accurate() {
        let v = sphere(5.0, 0.5, 26);
        let m = extract_isosurface(&v, 0.0);
        assert_eq!(m.open_edges(), 0, "surface must be closed");
        let r_err = m.vertices.iter().map(|p| (p.length() - 5.0).abs()).fold(0.0, f64::max);
        assert!(r_err < 0.05, "vertex off the sphere by {r_err} mm");
        let vol = m.signed_volume_mm3();
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 125.0;
        assert!(((vol - exact) / exact).abs() < 0.02, "volume {vol} vs {exact}");
    }

    #[test]
    fn touching_the_border_still_closes() {
        // A label volume that is inside right up to the border.
        let grid = Grid { dims: [5, 4, 3], spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
        let mut v = Volume::<f32>::zeros(grid);
        v.data.iter_mut().for_each(|x| *x = 1.0);
        v.data[grid.index(2, 1, 1)] = 0.0;
        let m = extract_isosurface(&v, 0.5);
        assert_eq!(m.open_edges(), 0);
        assert!(m.signed_volume_mm3() > 0.0);
    }
}
