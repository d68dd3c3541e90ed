//! Splitting a completed surface into what the prior already had and what is new.

use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::TriMesh;
use super::sample::sample_surface;

/// Splits `mesh` by triangle: `(near, far)` where a triangle is near when its centroid lies
/// within `distance_mm` of `reference` (sampled densely, every ≈ 0.1 mm²). Used to draw the
/// prior's part of a completed tree in one colour and the new vessels in another.
pub fn split_by_distance(mesh: &TriMesh, reference: &TriMesh, distance_mm: f64) -> (TriMesh, TriMesh) {
    if reference.is_empty() || mesh.is_empty() {
        return (TriMesh::default(), mesh.clone());
    }
    let n = ((reference.area_mm2() / 0.1) as usize).clamp(1000, 400_000);
    let pts: Vec<[f64; 3]> = sample_surface(reference, n, 0x5911).iter().map(|p| p.to_array()).collect();
    let tree: ImmutableKdTree<f64, 3> = match ImmutableKdTree::new_from_slice(&pts) {
        Ok(t) => t,
        Err(_) => return (TriMesh::default(), mesh.clone()),
    };
    let centroids: Vec<[f64; 3]> = mesh
        .faces
        .iter()
        .map(|f| (f.iter().map(|&i| mesh.vertices[i as usize]).sum::<DVec3>() / 3.0).to_array())
        .collect();
    let nearest = tree.query_batch(&centroids).nearest_one::<SquaredEuclidean<f64>>().execute();
    let (mut near, mut far) = (
        TriMesh { vertices: mesh.vertices.clone(), faces: vec![] },
        TriMesh { vertices: mesh.vertices.clone(), faces: vec![] },
    );
    for (f, r) in mesh.faces.iter().zip(&nearest) {
        if r.distance <= distance_mm * distance_mm { near.faces.push(*f) } else { far.faces.push(*f) }
    }
    (near, far)
}
