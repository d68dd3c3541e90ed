//! Centreline segments drawn as thin prisms, for pictures of centrelines.

use super::TriMesh;
use crate::data::tree::Segment;

/// One open prism of `sides` faces around each segment, radius = the segment's radius but at
/// least `min_radius_mm` (mm).
pub fn segment_tubes(segments: &[Segment], min_radius_mm: f64, sides: u32) -> TriMesh {
    let sides = sides.max(3);
    let mut mesh = TriMesh::default();
    for s in segments {
        let axis = s.end_mm - s.start_mm;
        if !(axis.length() > 0.0) {
            continue;
        }
        let dir = axis.normalize();
        let u = dir.any_orthonormal_vector();
        let v = dir.cross(u);
        let base = mesh.vertices.len() as u32;
        for (centre, r) in [(s.start_mm, s.start_radius_mm), (s.end_mm, s.end_radius_mm)] {
            let r = r.max(min_radius_mm);
            for k in 0..sides {
                let a = std::f64::consts::TAU * k as f64 / sides as f64;
                mesh.vertices.push(centre + r * (a.cos() * u + a.sin() * v));
            }
        }
        for k in 0..sides {
            let (a, b) = (base + k, base + (k + 1) % sides);
            let (c, d) = (a + sides, b + sides);
            mesh.faces.push([a, b, d]);
            mesh.faces.push([a, d, c]);
        }
    }
    mesh
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;

    #[test]
    fn a_prism_has_the_lateral_area_of_its_polygon() {
        let s = Segment {
            child: 0,
            start_mm: DVec3::ZERO,
            end_mm: DVec3::new(0.0, 0.0, 10.0),
            start_radius_mm: 1.0,
            end_radius_mm: 1.0,
        };
        let m = segment_tubes(&[s], 0.0, 6);
        assert_eq!(m.faces.len(), 12);
        // A regular hexagon of circumradius 1 has perimeter 6.
        assert!((m.area_mm2() - 60.0).abs() < 1e-9, "{}", m.area_mm2());
        let thin = Segment { start_radius_mm: 0.01, end_radius_mm: 0.01, ..s };
        assert!((segment_tubes(&[thin], 0.5, 6).area_mm2() - 30.0).abs() < 1e-9);
    }
}
