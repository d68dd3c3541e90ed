//! Triangle meshes in world millimetres: extraction from volumes, file formats, sampling.

pub mod distance;
pub mod io;
pub mod marching;
pub mod render_png;
pub mod sample;
pub mod split;
pub mod tubes;
pub mod voxelize;

use std::collections::HashMap;

use glam::DVec3;

/// An indexed triangle mesh (vertices in mm).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<DVec3>,
    pub faces: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Whether there is no triangle.
    pub fn is_empty(&self) -> bool {
        self.faces.is_empty()
    }

    /// Total surface area (mm²).
    pub fn area_mm2(&self) -> f64 {
        self.faces.iter().map(|f| self.face_area(f)).sum()
    }

    /// Area of one face (mm²).
    pub fn face_area(&self, f: &[u32; 3]) -> f64 {
        let [a, b, c] = f.map(|i| self.vertices[i as usize]);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Signed enclosed volume (mm³; positive for outward-facing triangles of a closed mesh).
    pub fn signed_volume_mm3(&self) -> f64 {
        self.faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| self.vertices[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// The surface moved `offset_mm` outward (negative: inward) along its vertex normals (the
    /// area-weighted mean of the faces' normals), outward taken from the sign of the enclosed
    /// volume; a vertex without a normal stays.
    pub fn offset(&self, offset_mm: f64) -> TriMesh {
        let mut normals = vec![DVec3::ZERO; self.vertices.len()];
        for f in &self.faces {
            let [a, b, c] = f.map(|i| self.vertices[i as usize]);
            let n = (b - a).cross(c - a);
            f.iter().for_each(|&i| normals[i as usize] += n);
        }
        let out = if self.signed_volume_mm3() < 0.0 { -offset_mm } else { offset_mm };
        let vertices = self
            .vertices
            .iter()
            .zip(&normals)
            .map(|(v, n)| *v + n.try_normalize().unwrap_or(DVec3::ZERO) * out)
            .collect();
        TriMesh { vertices, faces: self.faces.clone() }
    }

    /// Number of undirected edges not shared by exactly two faces (0 for a closed mesh).
    pub fn open_edges(&self) -> usize {
        let mut count: HashMap<(u32, u32), u32> = HashMap::new();
        for f in &self.faces {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        count.values().filter(|&&c| c != 2).count()
    }

    /// Axis-aligned bounds `(min, max)`, `None` when empty.
    pub fn bounds_mm(&self) -> Option<(DVec3, DVec3)> {
        let first = *self.vertices.first()?;
        Some(self.vertices.iter().fold((first, first), |(lo, hi), v| (lo.min(*v), hi.max(*v))))
    }

    /// The same faces with only the vertices they use (renumbered in first-use order).
    pub fn compacted(&self) -> TriMesh {
        let mut map: HashMap<u32, u32> = HashMap::new();
        let mut out = TriMesh::default();
        for f in &self.faces {
            out.faces.push(f.map(|i| {
                *map.entry(i).or_insert_with(|| {
                    out.vertices.push(self.vertices[i as usize]);
                    out.vertices.len() as u32 - 1
                })
            }));
        }
        out
    }

    /// Appends another mesh.
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.faces.extend(other.faces.iter().map(|f| f.map(|i| i + base)));
    }

    /// Splits the mesh into connected components (by shared vertices), largest first.
    pub fn components(&self) -> Vec<TriMesh> {
        let n = self.vertices.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(p: &mut [u32], mut x: u32) -> u32 {
            while p[x as usize] != x {
                p[x as usize] = p[p[x as usize] as usize];
                x = p[x as usize];
            }
            x
        }
        for f in &self.faces {
            let r0 = find(&mut parent, f[0]);
            for &v in &f[1..] {
                let r = find(&mut parent, v);
                if r != r0 {
                    parent[r as usize] = r0;
                }
            }
        }
        let mut by_root: HashMap<u32, Vec<[u32; 3]>> = HashMap::new();
        for f in &self.faces {
            let r = find(&mut parent, f[0]);
            by_root.entry(r).or_default().push(*f);
        }
        let mut parts: Vec<TriMesh> = by_root
            .into_values()
            .map(|faces| {
                let mut map: HashMap<u32, u32> = HashMap::new();
                let mut m = TriMesh::default();
                for f in faces {
                    let g = f.map(|v| {
                        *map.entry(v).or_insert_with(|| {
                            m.vertices.push(self.vertices[v as usize]);
                            m.vertices.len() as u32 - 1
                        })
                    });
                    m.faces.push(g);
                }
                m
            })
            .collect();
        parts.sort_by(|a, b| b.faces.len().cmp(&a.faces.len()).then(b.area_mm2().total_cmp(&a.area_mm2())));
        parts
    }

    /// Keeps the components whose area is at least `fraction` of the largest one's.
    pub fn without_small_islands(&self, fraction: f64) -> TriMesh {
        let parts = self.components();
        let Some(largest) = parts.first().map(TriMesh::area_mm2) else {
            return TriMesh::default();
        };
        let mut out = TriMesh::default();
        for p in parts.iter().filter(|p| p.area_mm2() >= fraction * largest) {
            out.append(p);
        }
        out
    }

    /// Keeps the connected components whose surface area is at least `min_area_mm2` (floaters
    /// removed); returns the kept mesh and the number of components dropped.
    pub fn without_islands_below(&self, min_area_mm2: f64) -> (TriMesh, usize) {
        let mut out = TriMesh::default();
        let mut dropped = 0;
        for p in self.components() {
            if p.area_mm2() >= min_area_mm2 {
                out.append(&p);
            } else {
                dropped += 1;
            }
        }
        (out, dropped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular octahedron of circumradius `r` (mm) about the origin, outward-facing.
    fn octahedron(r: f64) -> TriMesh {
        let vertices = vec![DVec3::X * r, -DVec3::X * r, DVec3::Y * r, -DVec3::Y * r, DVec3::Z * r, -DVec3::Z * r];
        let faces = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
        TriMesh { vertices, faces }
    }

    #[test]
    fn an_offset_moves_the_surface_outward_along_its_normals_whatever_way_it_faces() {
        let mesh = octahedron(2.0);
        assert!((mesh.signed_volume_mm3() - 4.0 / 3.0 * 8.0).abs() < 1e-9, "the oracle faces out");
        let grown = mesh.offset(0.5);
        assert!(grown.vertices.iter().zip(&octahedron(2.5).vertices).all(|(a, b)| a.distance(*b) < 1e-12));
        let inward = TriMesh { faces: mesh.faces.iter().map(|&[a, b, c]| [a, c, b]).collect(), ..mesh.clone() };
        assert!(inward.signed_volume_mm3() < 0.0);
        assert_eq!(inward.offset(0.5).vertices, grown.vertices, "outward by the enclosed volume's sign");
        let shrunk = mesh.offset(-0.5);
        assert!(shrunk.vertices.iter().zip(&octahedron(1.5).vertices).all(|(a, b)| a.distance(*b) < 1e-12));
    }
}
