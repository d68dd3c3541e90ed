//! Exact point-to-surface distances (mm): the distance from a point to the closest point of a
//! triangle mesh's triangles, through a bounding-volume hierarchy (parry3d). Unlike
//! nearest-neighbour distances between two point samples, this has no sampling floor: a surface
//! scored against itself is 0 whatever points are drawn on it.

use glam::DVec3;
use parry3d_f64::math::Vector;
use parry3d_f64::query::{PointQuery, Ray, RayCast};
use parry3d_f64::shape::TriMesh as ParryMesh;
use rayon::prelude::*;

use crate::data::mesh::TriMesh;

/// A triangle mesh prepared for closest-point queries.
pub struct SurfaceIndex {
    /// `None` for a mesh without triangles (every distance is then infinite).
    mesh: Option<ParryMesh>,
}

impl SurfaceIndex {
    /// Builds the hierarchy over the faces of `mesh` (non-finite vertices make no triangle).
    pub fn new(mesh: &TriMesh) -> Self {
        let vertices: Vec<Vector> = mesh.vertices.iter().map(|v| Vector::new(v.x, v.y, v.z)).collect();
        let faces: Vec<[u32; 3]> = mesh
            .faces
            .iter()
            .copied()
            .filter(|f| f.iter().all(|&i| mesh.vertices.get(i as usize).is_some_and(|v| v.is_finite())))
            .collect();
        let mesh = if faces.is_empty() { None } else { ParryMesh::new(vertices, faces).ok() };
        Self { mesh }
    }

    /// Whether the surface has no triangle.
    pub fn is_empty(&self) -> bool {
        self.mesh.is_none()
    }

    /// Distance (mm) from `p` to the surface (∞ for an empty surface).
    pub fn distance(&self, p: DVec3) -> f64 {
        match &self.mesh {
            None => f64::INFINITY,
            Some(m) => {
                // Project onto the triangles (not the enclosed solid): the unsigned distance.
                let q = Vector::new(p.x, p.y, p.z);
                (m.project_local_point(q, false).point - q).length()
            }
        }
    }

    /// The closest point of the surface to `p` (`None` for an empty surface).
    pub fn closest(&self, p: DVec3) -> Option<DVec3> {
        let m = self.mesh.as_ref()?;
        let q = m.project_local_point(Vector::new(p.x, p.y, p.z), false).point;
        Some(DVec3::new(q.x, q.y, q.z))
    }

    /// Distance (mm) along the unit direction `dir` from `origin` to the first triangle hit
    /// (`None`: nothing within `max_mm`).
    pub fn first_hit(&self, origin: DVec3, dir: DVec3, max_mm: f64) -> Option<f64> {
        let m = self.mesh.as_ref()?;
        let ray = Ray::new(Vector::new(origin.x, origin.y, origin.z), Vector::new(dir.x, dir.y, dir.z));
        m.cast_local_ray(&ray, max_mm, false)
    }

    /// Distances (mm) from every point to the surface, in parallel.
    pub fn distances(&self, points: &[DVec3]) -> Vec<f64> {
        points.par_iter().map(|&p| self.distance(p)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_to_one_triangle_face_edge_and_vertex() {
        let m = TriMesh {
            vertices: vec![DVec3::ZERO, DVec3::new(4.0, 0.0, 0.0), DVec3::new(0.0, 4.0, 0.0)],
            faces: vec![[0, 1, 2]],
        };
        let s = SurfaceIndex::new(&m);
        // Above the face, beyond an edge, beyond a vertex.
        assert!((s.distance(DVec3::new(1.0, 1.0, 3.0)) - 3.0).abs() < 1e-12);
        assert!((s.distance(DVec3::new(2.0, -2.0, 0.0)) - 2.0).abs() < 1e-12);
        assert!((s.distance(DVec3::new(-3.0, -4.0, 0.0)) - 5.0).abs() < 1e-12);
        assert_eq!(s.distance(DVec3::new(1.0, 1.0, 0.0)), 0.0);
        assert!(SurfaceIndex::new(&TriMesh::default()).distance(DVec3::ZERO).is_infinite());
        assert_eq!(s.closest(DVec3::new(1.0, 1.0, 3.0)), Some(DVec3::new(1.0, 1.0, 0.0)));
        let hit = s.first_hit(DVec3::new(1.0, 1.0, 3.0), DVec3::new(0.0, 0.0, -1.0), 10.0);
        assert!(hit.is_some_and(|t| (t - 3.0).abs() < 1e-12), "{hit:?}");
        assert_eq!(s.first_hit(DVec3::new(1.0, 1.0, 3.0), DVec3::Z, 10.0), None, "pointing away");
        assert_eq!(s.first_hit(DVec3::new(1.0, 1.0, 3.0), DVec3::new(0.0, 0.0, -1.0), 2.0), None, "too far");
    }
}
