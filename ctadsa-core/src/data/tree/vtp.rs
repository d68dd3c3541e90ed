//! Vessel trees as VTK XML PolyData (`.vtp`), the centreline format 3D Slicer, ParaView and
//! VMTK open: one polyline per branch (junction points shared), positions in mm, and per point
//! the radius (mm) — as `Radius` and under VMTK's name `MaximumInscribedSphereRadius` — and the
//! SWC type of the node (`SwcType`).

use std::fmt::Write as _;
use std::path::Path;

use super::VesselTree;
use crate::error::{Result, write_file};

/// One `<DataArray>` in ASCII.
fn data_array(out: &mut String, kind: &str, name: &str, components: usize, values: impl Iterator<Item = String>) {
    let _ = write!(out, "        <DataArray type=\"{kind}\" Name=\"{name}\"");
    if components > 1 {
        let _ = write!(out, " NumberOfComponents=\"{components}\"");
    }
    out.push_str(" format=\"ascii\">\n          ");
    for (i, v) in values.enumerate() {
        if i > 0 {
            out.push(if i % 12 == 0 { '\n' } else { ' ' });
        }
        out.push_str(&v);
    }
    out.push_str("\n        </DataArray>\n");
}

/// The tree as a `.vtp` document, with extra per-node `Float64` arrays `point_arrays` (name,
/// one value per node).
pub fn vtp_text(tree: &VesselTree, point_arrays: &[(&str, &[f64])]) -> String {
    let branches = tree.branches();
    let lines: usize = branches.len();
    let mut out = String::from("<?xml version=\"1.0\"?>\n");
    out.push_str("<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n");
    out.push_str("  <PolyData>\n");
    let _ = writeln!(
        out,
        "    <Piece NumberOfPoints=\"{}\" NumberOfVerts=\"0\" NumberOfLines=\"{lines}\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">",
        tree.nodes.len()
    );
    out.push_str("      <PointData Scalars=\"Radius\">\n");
    let radii = || tree.nodes.iter().map(|n| format!("{:.4}", n.radius_mm));
    data_array(&mut out, "Float64", "Radius", 1, radii());
    data_array(&mut out, "Float64", "MaximumInscribedSphereRadius", 1, radii());
    data_array(&mut out, "Int32", "SwcType", 1, tree.nodes.iter().map(|n| n.kind.to_string()));
    for (name, values) in point_arrays {
        data_array(&mut out, "Float64", name, 1, values.iter().map(|v| format!("{v:.4}")));
    }
    out.push_str("      </PointData>\n      <Points>\n");
    data_array(
        &mut out,
        "Float64",
        "Points",
        3,
        tree.nodes.iter().map(|n| {
            let p = n.position_mm;
            format!("{:.4} {:.4} {:.4}", p.x, p.y, p.z)
        }),
    );
    out.push_str("      </Points>\n      <Lines>\n");
    data_array(&mut out, "Int64", "connectivity", 1, branches.iter().flatten().map(|i| i.to_string()));
    let offsets = branches.iter().scan(0usize, |end, b| {
        *end += b.len();
        Some(end.to_string())
    });
    data_array(&mut out, "Int64", "offsets", 1, offsets);
    out.push_str("      </Lines>\n    </Piece>\n  </PolyData>\n</VTKFile>\n");
    out
}

/// Writes the tree as `.vtp` (atomically), with [`vtp_text`]'s extra `point_arrays`.
pub fn write_vtp(path: &Path, tree: &VesselTree, point_arrays: &[(&str, &[f64])]) -> Result<()> {
    write_file(path, vtp_text(tree, point_arrays).as_bytes())
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::data::tree::TreeNode;

    #[test]
    fn branches_become_polylines_that_share_the_junction() {
        let node = |x: f64, y: f64, parent: Option<usize>, kind: i32| TreeNode {
            id: 0,
            kind,
            position_mm: DVec3::new(x, y, 0.0),
            radius_mm: 1.0 + x / 10.0,
            parent,
        };
        // 0 - 1 - 2 (junction) - 3 - 4, and 2 - 5.
        let tree = VesselTree {
            nodes: vec![
                node(0.0, 0.0, None, 3),
                node(1.0, 0.0, Some(0), 3),
                node(2.0, 0.0, Some(1), 3),
                node(3.0, 0.0, Some(2), 3),
                node(4.0, 0.0, Some(3), 3),
                node(2.0, 1.0, Some(2), 4),
            ],
        };
        let confidence = [1.0, 1.0, 1.0, 1.0, 1.0, 0.25];
        let text = vtp_text(&tree, &[("Confidence", &confidence)]);
        assert!(text.contains("NumberOfPoints=\"6\"") && text.contains("NumberOfLines=\"3\""), "{text}");
        let array = |name: &str| {
            let start = text.find(&format!("Name=\"{name}\"")).unwrap();
            let body = &text[start..];
            let open = body.find('>').unwrap() + 1;
            let close = body.find("</DataArray>").unwrap();
            body[open..close].split_whitespace().map(str::to_string).collect::<Vec<_>>()
        };
        assert_eq!(array("connectivity"), ["0", "1", "2", "2", "3", "4", "2", "5"]);
        assert_eq!(array("offsets"), ["3", "6", "8"]);
        assert_eq!(array("SwcType"), ["3", "3", "3", "3", "3", "4"]);
        assert_eq!(array("Radius")[4], "1.4000");
        assert_eq!(array("Points").len(), 18);
        assert_eq!(array("Confidence")[5], "0.2500");
    }
}
