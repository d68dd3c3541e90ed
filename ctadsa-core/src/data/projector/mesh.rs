//! Cone-beam chord lengths of a closed triangle mesh: for every pixel, the length (mm) of its
//! ray inside the solid the mesh bounds. Exact for the mesh (no voxelisation): each triangle is
//! intersected with the rays of the pixels its projection covers, and the crossings along a ray,
//! sorted by depth, enter (+1) or leave (−1) the solid by the side of the triangle they cross.
//! The chord is the length where the count is not zero, so overlapping closed surfaces give
//! their union and an inward-facing mesh gives the same chords as an outward-facing one.

use ctadsa_render::ConeBeamView;
use glam::DVec3;
use rayon::prelude::*;

use crate::data::mesh::TriMesh;
use crate::error::{CoreError, Result};

/// Most ray–triangle tests one view may take (the pixels under the triangles' projected
/// bounding boxes, summed): about a minute on two cores. A vessel mesh of a million small
/// triangles takes a few million.
pub const MAX_RAY_TESTS: u64 = 4_000_000_000;

/// Depth `t` (mm from the source) where the ray `source + t·dir` crosses triangle `a b c`, and
/// whether it enters through the triangle's front (`dir · n < 0`, `n = (b − a) × (c − a)`).
/// Möller–Trumbore; edges count as inside.
fn crossing(source: DVec3, dir: DVec3, [a, b, c]: [DVec3; 3]) -> Option<(f64, bool)> {
    let (e1, e2) = (b - a, c - a);
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = source - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some((t, dir.dot(e1.cross(e2)) < 0.0))
}

/// Length (mm) where the running count of crossings (enter +1, leave −1), taken in depth order,
/// is not zero; `None` when the count does not return to zero (the ray met an open surface, or
/// crossed exactly on an edge and counted it twice).
fn inside_length(mut crossings: Vec<(f64, bool)>) -> Option<f64> {
    crossings.sort_by(|x, y| x.0.total_cmp(&y.0));
    let (mut depth, mut length, mut since) = (0i32, 0.0, 0.0);
    for (t, enters) in crossings {
        let before = depth;
        depth += if enters { 1 } else { -1 };
        if before == 0 {
            since = t;
        } else if depth == 0 {
            length += t - since;
        }
    }
    (depth == 0).then_some(length)
}

/// Chord length (mm) of every pixel's ray through the closed `mesh` in `view`, row-major
/// `H × W`; NaN where the crossings do not pair up (an open mesh, or a ray exactly through an
/// edge). Pixel `(col, row)` is the ray through pixel position `(col, row)`, as everywhere else.
/// An error, before any work, when the triangles' projections would take more than
/// [`MAX_RAY_TESTS`] ray tests (a mesh of huge triangles, or one far larger than the view).
pub fn mesh_chords(mesh: &TriMesh, view: &ConeBeamView) -> Result<Vec<f32>> {
    let (w, h) = (view.width() as usize, view.height() as usize);
    let source = view.source_mm();
    // The triangles whose projection may cover each row's pixel centres, with their columns.
    let mut spans: Vec<(u32, [usize; 4])> = Vec::new();
    let mut tests = 0u64;
    for (fi, f) in mesh.faces.iter().enumerate() {
        let uv: Option<Vec<_>> = f.iter().map(|&i| view.project(mesh.vertices[i as usize])).collect();
        let Some(uv) = uv else { continue };
        let lo = uv.iter().fold(glam::DVec2::splat(f64::INFINITY), |m, p| m.min(*p)).ceil();
        let hi = uv.iter().fold(glam::DVec2::splat(f64::NEG_INFINITY), |m, p| m.max(*p)).floor();
        if !(lo.is_finite() && hi.is_finite()) || hi.x < 0.0 || hi.y < 0.0 || lo.x >= w as f64 || lo.y >= h as f64 {
            continue;
        }
        let (c0, c1) = (lo.x.max(0.0) as usize, (hi.x as usize).min(w - 1));
        let (r0, r1) = (lo.y.max(0.0) as usize, (hi.y as usize).min(h - 1));
        if c0 > c1 || r0 > r1 {
            continue; // between pixel centres
        }
        tests += ((c1 - c0 + 1) * (r1 - r0 + 1)) as u64;
        if tests > MAX_RAY_TESTS {
            return Err(CoreError::invalid(format!(
                "the mesh's {} triangles cover more than {MAX_RAY_TESTS} pixels of a {w} × {h} view (triangles far larger than a pixel): too large to project",
                mesh.faces.len()
            )));
        }
        spans.push((fi as u32, [c0, c1, r0, r1]));
    }
    let mut by_row: Vec<Vec<(u32, usize, usize)>> = vec![Vec::new(); h];
    for (fi, [c0, c1, r0, r1]) in spans {
        for row in by_row.iter_mut().take(r1 + 1).skip(r0) {
            row.push((fi, c0, c1));
        }
    }
    let mut chords = vec![0.0f32; w * h];
    chords.par_chunks_mut(w).zip(&by_row).enumerate().for_each(|(row, (out, faces))| {
        if faces.is_empty() {
            return;
        }
        let mut hits: Vec<Vec<(f64, bool)>> = vec![Vec::new(); w];
        for &(fi, c0, c1) in faces {
            let tri = mesh.faces[fi as usize].map(|i| mesh.vertices[i as usize]);
            for (col, hit) in hits.iter_mut().enumerate().take(c1 + 1).skip(c0) {
                if let Some(x) = crossing(source, view.pixel_ray(col as f64, row as f64), tri) {
                    hit.push(x);
                }
            }
        }
        for (o, hit) in out.iter_mut().zip(hits) {
            if !hit.is_empty() {
                *o = inside_length(hit).map_or(f32::NAN, |l| l as f32);
            }
        }
    });
    Ok(chords)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use ctadsa_render::TigreGeometry;

    /// An axis-aligned box `lo..hi` (mm) as 12 outward-facing triangles.
    pub(crate) fn box_mesh(lo: [f64; 3], hi: [f64; 3]) -> TriMesh {
        let v = |i: usize| {
            DVec3::new(
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            )
        };
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let mut faces = Vec::new();
        for [a, b, c, d] in quads {
            faces.push([a, b, c]);
            faces.push([a, c, d]);
        }
        TriMesh { vertices: (0..8).map(v).collect(), faces }
    }

    /// Length (mm) of `source + t·dir` inside the box (slab method), the oracle.
    fn box_chord(lo: [f64; 3], hi: [f64; 3], source: DVec3, dir: DVec3) -> f64 {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let (ta, tb) = ((lo[a] - source[a]) / dir[a], (hi[a] - source[a]) / dir[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        (t1 - t0).max(0.0)
    }

    pub(crate) fn view() -> ConeBeamView {
        ConeBeamView::from_tigre(&TigreGeometry { detector_px: [64, 48], ..TigreGeometry::reference(-60.0) }).unwrap()
    }

    #[test]
    fn the_chords_of_a_box_are_its_slab_lengths() {
        let (lo, hi) = ([-7.3, -4.1, -5.2], [6.1, 3.9, 2.7]);
        let mesh = box_mesh(lo, hi);
        assert!(mesh.signed_volume_mm3() > 0.0 && mesh.open_edges() == 0, "the oracle mesh faces out and is closed");
        let view = view();
        let chords = mesh_chords(&mesh, &view).unwrap();
        let (mut inside, mut worst) = (0, 0.0f64);
        for row in 0..48 {
            for col in 0..64 {
                let exact = box_chord(lo, hi, view.source_mm(), view.pixel_ray(col as f64, row as f64));
                let got = chords[row * 64 + col] as f64;
                assert!(!got.is_nan(), "pixel ({col}, {row}) is undefined");
                worst = worst.max((got - exact).abs());
                inside += usize::from(exact > 0.0);
            }
        }
        assert!(worst < 1e-4, "worst chord error {worst} mm");
        assert!(inside > 100 && inside < 64 * 48, "the box covers part of the detector ({inside} px)");
        // Turned inside out, the mesh bounds the same solid.
        let flipped = TriMesh { faces: mesh.faces.iter().map(|&[a, b, c]| [a, c, b]).collect(), ..mesh };
        assert_eq!(mesh_chords(&flipped, &view).unwrap(), chords);
    }

    #[test]
    fn overlapping_boxes_give_their_union_and_an_open_mesh_gives_nan() {
        let (a, b) = (([-6.0, -3.0, -3.0], [2.0, 3.0, 3.0]), ([-2.0, -3.0, -3.0], [6.0, 3.0, 3.0]));
        let mut both = box_mesh(a.0, a.1);
        both.append(&box_mesh(b.0, b.1));
        let union = box_mesh([-6.0, -3.0, -3.0], [6.0, 3.0, 3.0]);
        let view = view();
        let (got, exact) = (mesh_chords(&both, &view).unwrap(), mesh_chords(&union, &view).unwrap());
        let worst = got.iter().zip(&exact).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "worst {worst} mm");
        // Without one face the rays through it cross once: unknown, not a wrong length.
        let mut open = union.clone();
        open.faces.truncate(11);
        let chords = mesh_chords(&open, &view).unwrap();
        assert!(chords.iter().any(|c| c.is_nan()));
        assert!(chords.iter().zip(&exact).all(|(c, e)| c.is_nan() || (c - e).abs() < 1e-4));
    }

    #[test]
    fn a_mesh_of_huge_triangles_is_refused_before_any_work() {
        // A triangle that covers the whole detector, 250 mm from the source.
        let covering = |view: &ConeBeamView| {
            let (w, h) = (view.width() as f64, view.height() as f64);
            let at = |u: f64, v: f64| view.source_mm() + 250.0 * view.pixel_ray(u, v);
            TriMesh { vertices: vec![at(-w, -h), at(3.0 * w, -h), at(-w, 3.0 * h)], faces: vec![[0, 1, 2]] }
        };
        let started = std::time::Instant::now();
        // 1,000 of them on 64 × 48 pixels: 3 million tests, fine (every ray crosses each once:
        // the crossings do not pair up).
        let small = view();
        let mesh = TriMesh { faces: vec![[0, 1, 2]; 1000], ..covering(&small) };
        let chords = mesh_chords(&mesh, &small).expect("within the limit");
        assert!(chords.iter().all(|c| c.is_nan()));
        // 300 of them on 4096² pixels: 5 billion, refused.
        let large = ConeBeamView::from_tigre(&TigreGeometry {
            detector_px: [4096, 4096],
            pixel_mm: [0.1, 0.1],
            ..TigreGeometry::reference(0.0)
        })
        .unwrap();
        let mesh = TriMesh { faces: vec![[0, 1, 2]; 300], ..covering(&large) };
        match mesh_chords(&mesh, &large) {
            Err(e) => assert!(e.to_string().contains("too large to project"), "{e}"),
            Ok(_) => panic!("5 billion ray tests accepted"),
        }
        assert!(started.elapsed().as_secs() < 30, "{:?}", started.elapsed());
    }
}
