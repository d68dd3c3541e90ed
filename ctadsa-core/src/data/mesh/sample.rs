//! Area-uniform random points on a mesh surface (seeded, reproducible).

use glam::DVec3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::TriMesh;

/// `count` points distributed uniformly by area over the surface, from `seed`. Empty for an
/// empty or zero-area mesh.
pub fn sample_surface(mesh: &TriMesh, count: usize, seed: u64) -> Vec<DVec3> {
    let mut cumulative = Vec::with_capacity(mesh.faces.len());
    let mut total = 0.0;
    for f in &mesh.faces {
        total += mesh.face_area(f);
        cumulative.push(total);
    }
    if !(total > 0.0) || count == 0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| {
            let r = rng.random_range(0.0..total);
            let fi = cumulative.partition_point(|&c| c <= r).min(mesh.faces.len() - 1);
            let [a, b, c] = mesh.faces[fi].map(|i| mesh.vertices[i as usize]);
            let (u, v): (f64, f64) = (rng.random(), rng.random());
            let su = u.sqrt();
            a * (1.0 - su) + b * (su * (1.0 - v)) + c * (su * v)
        })
        .collect()
}

/// Centroid of a point set (`None` when empty).
pub fn centroid(points: &[DVec3]) -> Option<DVec3> {
    (!points.is_empty()).then(|| points.iter().sum::<DVec3>() / points.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn area_uniform_on_two_unequal_triangles() {
        // Triangle A has area 0.5, triangle B area 4.5: B should get 90% of the points.
        let mesh = TriMesh {
            vertices: vec![
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
                DVec3::new(10.0, 0.0, 0.0),
                DVec3::new(13.0, 0.0, 0.0),
                DVec3::new(10.0, 3.0, 0.0),
            ],
            faces: vec![[0, 1, 2], [3, 4, 5]],
        };
        let pts = sample_surface(&mesh, 20_000, 9);
        let in_b = pts.iter().filter(|p| p.x >= 10.0).count() as f64 / pts.len() as f64;
        assert!((in_b - 0.9).abs() < 0.01, "{in_b}");
        assert_eq!(pts, sample_surface(&mesh, 20_000, 9), "seeded");
        assert!(pts.iter().all(|p| p.z == 0.0));
    }
}
