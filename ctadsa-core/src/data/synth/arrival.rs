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
/// every segment sampled every 0.1 mm, each point's frame written to the pixel it projects
/// into where that is earlier.
pub fn arrival_map(tree: &VesselTree, view: &ConeBeamView, spec: &ArrivalSpec) -> Image {
    let (w, h) = (view.width(), view.height());
    let mut first = vec![f32::INFINITY; (w * h) as usize];
    let length = path_lengths(tree);
    for s in tree.segments() {
        let parent = tree.nodes[s.child].parent.unwrap_or(s.child);
        let (start, span) = (length[parent], s.length_mm());
        let n = (span / SAMPLE_MM).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = (k as f64 + 0.5) / n as f64;
            let Some(uv) = view.project(s.start_mm.lerp(s.end_mm, t)) else { continue };
            let (u, v) = (uv.x.round(), uv.y.round());
            if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                continue;
            }
            let px = &mut first[v as usize * w as usize + u as usize];
            *px = px.min(spec.frame(start + t * span));
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
        TreeNode { id, kind: 0, position_mm: DVec3::from(p), radius_mm: 0.5, parent }
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
        let mut g = TigreGeometry::reference(-90.0);
        g.detector_px = [64, 64];
        g.pixel_mm = [1.0, 1.0];
        let view = ConeBeamView::from_tigre(&g).unwrap();
        let map = arrival_map(&tree, &view, &ArrivalSpec { frames_per_s: 10.0, flow_mm_s: 100.0 });
        for (z, frame) in [(-19.0, 0.0), (-5.0, 1.0), (5.0, 2.0), (19.0, 3.0)] {
            let uv = view.project(DVec3::new(0.0, 0.0, z)).unwrap();
            let at = map.data[uv.y.round() as usize * 64 + uv.x.round() as usize];
            assert_eq!(at, frame, "at z = {z} mm");
        }
        let filled = map.data.iter().filter(|&&f| f != NO_ARRIVAL).count();
        let column = view.project(DVec3::ZERO).unwrap().x.round() as usize;
        assert!(filled > 40 && map.data.iter().enumerate().all(|(i, &f)| f == NO_ARRIVAL || i % 64 == column));
    }
}
