//! Arrival maps of a simulated time-resolved run: contrast injected at every root of the tree at
//! once flows along it at one velocity, and the run is sampled at a fixed frame rate; a pixel's
//! arrival is the frame at which the first vessel along its ray fills (what thresholding a
//! time-resolved DSA run pixel by pixel gives).

use ctadsa_render::ConeBeamView;
use serde::{Deserialize, Serialize};

use crate::data::case::images::{Image, NO_ARRIVAL};
use crate::data::tree::VesselTree;
use crate::error::{CoreError, Result};

/// Step (mm) between the points sampled along each segment.
const SAMPLE_MM: f64 = 0.1;

/// How the simulated run samples the bolus.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrivalSpec {
    /// Frames per second of the run (neuro DSA: 2–7.5).
    pub frames_per_s: f64,
    /// Velocity (mm/s) of the contrast along every vessel.
    pub flow_mm_s: f64,
}

impl ArrivalSpec {
    /// Range checks; the error names the setting.
    pub fn validate(&self) -> Result<()> {
        if !(self.frames_per_s > 0.0 && self.frames_per_s <= 1000.0) {
            return Err(CoreError::invalid(format!(
                "arrival frame rate must be in (0, 1000] /s, got {}",
                self.frames_per_s
            )));
        }
        if !(self.flow_mm_s > 0.0 && self.flow_mm_s <= 100_000.0) {
            return Err(CoreError::invalid(format!(
                "flow velocity must be in (0, 100000] mm/s, got {}",
                self.flow_mm_s
            )));
        }
        Ok(())
    }

    /// The frame in which contrast that has flowed `path_mm` arrives.
    fn frame(&self, path_mm: f64) -> f32 {
        (path_mm / self.flow_mm_s * self.frames_per_s).floor() as f32
    }
}

/// Path length (mm) from each node's root along the tree.
fn path_lengths(tree: &VesselTree) -> Vec<f64> {
    let children = tree.children();
    let mut length = vec![0.0; tree.nodes.len()];
    let mut stack: Vec<usize> = (0..tree.nodes.len()).filter(|&i| tree.nodes[i].parent.is_none()).collect();
    while let Some(i) = stack.pop() {
        for &c in &children[i] {
            length[c] = length[i] + tree.nodes[c].position_mm.distance(tree.nodes[i].position_mm);
            stack.push(c);
        }
    }
    length
}

/// The arrival map of `view` (its detector's size; frames, [`NO_ARRIVAL`] where no vessel fills):
/// every segment sampled every 0.1 mm, each point's frame written, where that is earlier, to
/// every pixel whose centre lies within the vessel's projected radius of the point's projection
/// (the pixel it projects into always, so a sub-pixel vessel still fills one): a vessel fills
/// its whole projected width, and hides a later one behind it there.
pub fn arrival_map(tree: &VesselTree, view: &ConeBeamView, spec: &ArrivalSpec) -> Image {
    let (w, h) = (view.width(), view.height());
    let mut first = vec![f32::INFINITY; (w * h) as usize];
    let length = path_lengths(tree);
    let focal_px = view.intrinsics().focal_px[0].abs().max(view.intrinsics().focal_px[1].abs());
    for s in tree.segments() {
        let parent = tree.nodes[s.child].parent.unwrap_or(s.child);
        let (start, span) = (length[parent], s.length_mm());
        let n = (span / SAMPLE_MM).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = (k as f64 + 0.5) / n as f64;
            let p = s.start_mm.lerp(s.end_mm, t);
            let Some(uv) = view.project(p) else { continue };
            let radius_px = focal_px * (s.start_radius_mm + t * (s.end_radius_mm - s.start_radius_mm)).max(0.0)
                / view.to_camera(p).z;
            let frame = spec.frame(start + t * span);
            let (u0, v0) = (uv.x.round(), uv.y.round());
            let reach = radius_px.ceil().min(w.max(h) as f64);
            let mut mark = |u: f64, v: f64| {
                if u >= 0.0 && v >= 0.0 && u < w as f64 && v < h as f64 {
                    let px = &mut first[v as usize * w as usize + u as usize];
                    *px = px.min(frame);
                }
            };
            mark(u0, v0);
            for dv in -reach as i64..=reach as i64 {
                for du in -reach as i64..=reach as i64 {
                    let (u, v) = (u0 + du as f64, v0 + dv as f64);
                    if (u - uv.x).powi(2) + (v - uv.y).powi(2) <= radius_px * radius_px {
                        mark(u, v);
                    }
                }
            }
        }
    }
    Image { width: w, height: h, data: first.into_iter().map(|f| if f.is_finite() { f } else { NO_ARRIVAL }).collect() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::tree::TreeNode;
    use ctadsa_render::TigreGeometry;
    use glam::DVec3;

    fn node(id: i64, parent: Option<usize>, p: [f64; 3]) -> TreeNode {
        wide_node(id, parent, p, 0.5)
    }

    fn wide_node(id: i64, parent: Option<usize>, p: [f64; 3], radius_mm: f64) -> TreeNode {
        TreeNode { id, kind: 0, position_mm: DVec3::from(p), radius_mm, parent }
    }

    /// The reference geometry at −90° shrunk to 64² detector pixels of 1 mm.
    fn small_view() -> ConeBeamView {
        let mut g = TigreGeometry::reference(-90.0);
        g.detector_px = [64, 64];
        g.pixel_mm = [1.0, 1.0];
        ConeBeamView::from_tigre(&g).unwrap()
    }

    /// A vessel along z from its root: frames grow with the path length (at 100 mm/s and 10
    /// frames/s, one frame per 10 mm), each in the pixels the vessel projects into, and nowhere
    /// else.
    #[test]
    fn frames_follow_the_path_length_from_the_root() {
        let tree = VesselTree {
            nodes: vec![
                node(1, None, [0.0, 0.0, -20.0]),
                node(2, Some(0), [0.0, 0.0, 0.0]),
                node(3, Some(1), [0.0, 0.0, 20.0]),
            ],
        };
        let view = small_view();
        let map = arrival_map(&tree, &view, &ArrivalSpec { frames_per_s: 10.0, flow_mm_s: 100.0 });
        for (z, frame) in [(-19.0, 0.0), (-5.0, 1.0), (5.0, 2.0), (19.0, 3.0)] {
            let uv = view.project(DVec3::new(0.0, 0.0, z)).unwrap();
            let at = map.data[uv.y.round() as usize * 64 + uv.x.round() as usize];
            assert_eq!(at, frame, "at z = {z} mm");
        }
        // Filled: the pixels within the vessel's projected radius of its axis, and nowhere else.
        let axis = view.project(DVec3::ZERO).unwrap().x;
        let radius_px = 0.5 * view.intrinsics().focal_px[0] / view.to_camera(DVec3::ZERO).z;
        let filled = map.data.iter().filter(|&&f| f != NO_ARRIVAL).count();
        assert!(filled > 40);
        for (i, &f) in map.data.iter().enumerate() {
            let off = ((i % 64) as f64 - axis).abs();
            assert!(f == NO_ARRIVAL || off <= radius_px.max(0.5) + 1e-9, "pixel {i} filled {off} px off the axis");
        }
    }

    /// A wide vessel fills its whole projected width (not only the pixels its axis crosses), and
    /// a later thin one crossing in front of or behind it shows the wide one's frame there.
    #[test]
    fn a_vessel_fills_its_projected_width_and_hides_a_later_one() {
        let view = small_view();
        let across = view.rotation().row(0); // the world direction of the image's u axis
        let at_z = |a: f64, z: f64| (across * a + DVec3::new(0.0, 0.0, z)).to_array();
        // The wide vessel (radius 4 mm) from z = -20 to 20 mm; the thin one (0.2 mm) leaves its
        // end, runs down 20 mm across from it, then back across its projection at z = 0.
        let tree = VesselTree {
            nodes: vec![
                wide_node(1, None, at_z(0.0, -20.0), 4.0),
                wide_node(2, Some(0), at_z(0.0, 20.0), 4.0),
                wide_node(3, Some(1), at_z(20.0, 20.0), 0.2),
                wide_node(4, Some(2), at_z(20.0, 0.0), 0.2),
                wide_node(5, Some(3), at_z(-20.0, 0.0), 0.2),
            ],
        };
        let map = arrival_map(&tree, &view, &ArrivalSpec { frames_per_s: 10.0, flow_mm_s: 100.0 });
        let at = |a: f64, z: f64| {
            let uv = view.project(DVec3::from(at_z(a, z))).unwrap();
            map.data[uv.y.round() as usize * 64 + uv.x.round() as usize]
        };
        // 3 mm beside the wide vessel's axis (inside its radius), near its root: its first frame.
        assert_eq!(at(3.0, -17.0), 0.0);
        // The thin vessel 3 mm beside the axis at z = 0 (its path from the root 97 mm, frame 9)
        // shows the wide vessel's frame there (paths of 17-23 mm within reach: frame 1 or 2) ...
        assert!(at(3.0, 0.0) <= 2.0, "got {}", at(3.0, 0.0));
        // ... and its own beyond the wide vessel's width (paths 88 and 112 mm: frames 8 and 11).
        assert_eq!(at(12.0, 0.0), 8.0);
        assert_eq!(at(-12.0, 0.0), 11.0);
    }
}
