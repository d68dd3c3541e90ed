//! Whether a prior mesh lies where the case's views look.
//!
//! A prior must be in the case's world coordinates (mm, isocentre at the origin). One written in
//! another frame — voxel indices, a scanner's patient coordinates, metres — would otherwise
//! stretch the run's working box over both the views' field and the mesh, allocate a grid for
//! the empty space between them and train on nothing: a long run with a silently wrong answer.

use std::path::Path;

use ctadsa_render::ConeBeamView;

use crate::data::mesh::TriMesh;
use crate::error::{CoreError, Result};

/// Refuses a prior whose triangles have no area (nothing to place Gaussians on), with a vertex
/// as far from the isocentre as an X-ray source (no anatomy the views image lies there), smaller
/// than one detector pixel at the isocentre (another unit), or with no vertex that projects onto
/// every view's detector.
pub fn check_prior_in_views(mesh: &TriMesh, views: &[ConeBeamView], path: &Path) -> Result<()> {
    let area = mesh.area_mm2();
    if !(area > 0.0 && area.is_finite()) {
        return Err(CoreError::format(
            path,
            format!(
                "the prior's {} triangles have a total area of {area} mm²: every one is degenerate",
                mesh.faces.len()
            ),
        ));
    }
    let Some(nearest_source_mm) = views.iter().map(|v| v.source_mm().length()).reduce(f64::min) else {
        return Ok(());
    };
    if let Some((i, p)) = mesh.vertices.iter().enumerate().find(|(_, p)| p.length() >= nearest_source_mm) {
        return Err(CoreError::format(
            path,
            format!(
                "vertex {i} at ({}, {}, {}) mm lies {} mm from the isocentre, as far as the nearest X-ray source \
                 ({nearest_source_mm:.1} mm): the prior must be in the case's world coordinates (mm, isocentre at \
                 the origin)",
                mm(p.x),
                mm(p.y),
                mm(p.z),
                mm(p.length())
            ),
        ));
    }
    // One detector pixel seen at the isocentre (mm): a prior smaller than that (a tree written
    // in metres spans a fraction of a millimetre) is in another unit.
    let pixel_at_isocentre_mm = views
        .iter()
        .map(|v| v.source_mm().length() / v.intrinsics().focal_px[0].abs().max(v.intrinsics().focal_px[1].abs()))
        .fold(f64::INFINITY, f64::min);
    let (lo, hi) = mesh.bounds_mm().unwrap_or_default();
    let span = (hi - lo).length();
    if span < pixel_at_isocentre_mm {
        return Err(CoreError::format(
            path,
            format!(
                "the prior spans {span:.4} mm (box diagonal), less than one detector pixel at the isocentre \
                 ({pixel_at_isocentre_mm:.2} mm): it must be in mm (metres?)"
            ),
        ));
    }
    let on_every_detector = |p: &glam::DVec3| {
        views.iter().all(|v| {
            v.project(*p).is_some_and(|uv| {
                (-0.5..v.width() as f64 - 0.5).contains(&uv.x) && (-0.5..v.height() as f64 - 0.5).contains(&uv.y)
            })
        })
    };
    if !mesh.vertices.iter().any(on_every_detector) {
        return Err(CoreError::format(
            path,
            format!(
                "no vertex of the prior projects onto every view's detector (the prior spans ({:.1}, {:.1}, {:.1}) to \
                 ({:.1}, {:.1}, {:.1}) mm): it must be in the case's world coordinates (mm, isocentre at the origin) \
                 and overlap the views' field",
                lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
            ),
        ));
    }
    Ok(())
}

/// A coordinate (mm) for a message: one decimal, or three significant digits when huge.
fn mm(v: f64) -> String {
    if v.abs() < 1e6 { format!("{v:.1}") } else { format!("{v:.2e}") }
}

#[cfg(test)]
mod tests {
    use ctadsa_render::TigreGeometry;
    use glam::DVec3;

    use super::*;

    fn views() -> Vec<ConeBeamView> {
        [-90.0, 0.0].map(|a| ConeBeamView::from_tigre(&TigreGeometry::reference(a)).unwrap()).to_vec()
    }

    fn triangle_at(centre: DVec3) -> TriMesh {
        let d = [DVec3::ZERO, DVec3::X, DVec3::Y];
        TriMesh { vertices: d.iter().map(|o| centre + *o).collect(), faces: vec![[0, 1, 2]] }
    }

    #[test]
    fn a_prior_at_the_isocentre_passes() {
        check_prior_in_views(&triangle_at(DVec3::new(5.0, -3.0, 10.0)), &views(), Path::new("p.obj")).unwrap();
    }

    #[test]
    fn a_prior_beside_the_field_is_refused_naming_the_file() {
        // 300 mm to the side: in front of both sources (DSO 500 mm) but off both 256 mm detectors.
        let err = check_prior_in_views(&triangle_at(DVec3::new(300.0, 300.0, 0.0)), &views(), Path::new("p.obj"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("p.obj") && err.contains("projects onto every view"), "{err}");
    }

    #[test]
    fn a_prior_without_area_is_refused() {
        let mut mesh = triangle_at(DVec3::ZERO);
        mesh.vertices[2] = DVec3::new(2.0, 0.0, 0.0); // collinear
        let err = check_prior_in_views(&mesh, &views(), Path::new("p.obj")).unwrap_err().to_string();
        assert!(err.contains("p.obj") && err.contains("degenerate"), "{err}");
    }

    #[test]
    fn a_prior_in_metres_is_refused() {
        let mesh = triangle_at(DVec3::ZERO);
        let metres = TriMesh { vertices: mesh.vertices.iter().map(|v| *v * 1e-3).collect(), faces: mesh.faces };
        let err = check_prior_in_views(&metres, &views(), Path::new("p.obj")).unwrap_err().to_string();
        assert!(err.contains("p.obj") && err.contains("one detector pixel"), "{err}");
    }

    #[test]
    fn a_vertex_beyond_the_sources_is_refused_naming_it() {
        let mut mesh = triangle_at(DVec3::ZERO);
        mesh.vertices[2] = DVec3::new(0.0, 0.0, 1e30);
        let err = check_prior_in_views(&mesh, &views(), Path::new("p.obj")).unwrap_err().to_string();
        assert!(err.contains("vertex 2") && err.contains("nearest X-ray source (500.0 mm)"), "{err}");
    }
}
