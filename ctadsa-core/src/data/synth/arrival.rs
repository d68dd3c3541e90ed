//! Arrival maps of a simulated time-resolved run: contrast injected at every root of the tree at
//! once flows along it, and the run is sampled at a fixed frame rate; a pixel's arrival is the
//! frame at which the first vessel along its ray fills (what thresholding a time-resolved DSA run
//! pixel by pixel gives). By default the maps are ideal — one velocity everywhere, the frame
//! exact, both planes imaged at the same instants; [`ArrivalSpec`] can make them as a real run's
//! are: velocities that differ between vessels, a detected frame off by a frame here and there,
//! and the planes of a biplane system imaged alternately.

use ctadsa_render::ConeBeamView;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::data::case::images::{Image, NO_ARRIVAL};
use crate::data::projector::noise::standard_normal;
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
    /// Velocity (mm/s) of the contrast along the vessels (their median with `velocity_spread`).
    pub flow_mm_s: f64,
    /// How much the velocity differs between vessels: each segment's is `flow_mm_s` ×
    /// e^(σ N(0,1)) with σ this (0: one velocity everywhere; 0.3 puts two thirds of the
    /// segments between 0.74 and 1.35 × `flow_mm_s`).
    #[serde(default, skip_serializing_if = "crate::data::case::is_zero")]
    pub velocity_spread: f64,
    /// Error of each pixel's detected frame: N(0, σ²) frames with σ this, rounded, never
    /// before frame 0 (0: exact; 0.5 moves a third of the pixels by a frame or more).
    #[serde(default, skip_serializing_if = "crate::data::case::is_zero")]
    pub frame_noise: f64,
    /// Delay (frames) of every second view's frames: a biplane system images its planes
    /// alternately, the lateral half a frame after the frontal (0.5); 0: at the same instants.
    #[serde(default, skip_serializing_if = "crate::data::case::is_zero")]
    pub interleave_frames: f64,
    /// Seed of the velocities' and the frame errors' draws.
    #[serde(default, skip_serializing_if = "is_zero_seed")]
    pub seed: u64,
}

fn is_zero_seed(v: &u64) -> bool {
    *v == 0
}

impl ArrivalSpec {
    /// An ideal run: one velocity everywhere, exact frames, both planes at the same instants.
    pub const fn ideal(frames_per_s: f64, flow_mm_s: f64) -> Self {
        Self { frames_per_s, flow_mm_s, velocity_spread: 0.0, frame_noise: 0.0, interleave_frames: 0.0, seed: 0 }
    }

    /// Range checks; the error names the setting.
    pub fn validate(&self) -> Result<()> {
        if !(self.frames_per_s >= 0.1 && self.frames_per_s <= 1000.0) {
            return Err(CoreError::invalid(format!(
                "arrival frame rate must be in [0.1, 1000] /s, got {}",
                self.frames_per_s
            )));
        }
        if !(self.flow_mm_s > 0.0 && self.flow_mm_s <= 100_000.0) {
            return Err(CoreError::invalid(format!(
                "flow velocity must be in (0, 100000] mm/s, got {}",
                self.flow_mm_s
            )));
        }
        for (what, value, max) in [
            ("arrival velocity spread", self.velocity_spread, 2.0),
            ("arrival frame noise (frames)", self.frame_noise, 100.0),
            ("arrival interleave (frames)", self.interleave_frames, 1.0),
        ] {
            if !(value.is_finite() && (0.0..=max).contains(&value)) {
                return Err(CoreError::invalid(format!("{what} must be in [0, {max}], got {value}")));
            }
        }
        Ok(())
    }

    /// How late (frames) the `index`-th view's frames are: `interleave_frames` for every second
    /// view, 0 for the others ([`crate::data::case::ViewEntry::arrival_offset_frames`]).
    pub fn delay_frames(&self, index: usize) -> f64 {
        if index % 2 == 1 { self.interleave_frames } else { 0.0 }
    }

    /// The frame in which contrast shows that has travelled `path_mm` at `flow_mm_s` (or as long
    /// at the vessels' own velocities: [`ArrivalSpec::slowness`]), in a view whose frames are
    /// `delay_frames` late.
    fn frame(&self, path_mm: f64, delay_frames: f64) -> f32 {
        (path_mm / self.flow_mm_s * self.frames_per_s - delay_frames).floor().max(0.0) as f32
    }

    /// Per node, how much slower than `flow_mm_s` the contrast runs along the segment from its
    /// parent (`flow_mm_s` / its velocity; 1 without `velocity_spread`), drawn in node order.
    fn slowness(&self, tree: &VesselTree) -> Vec<f64> {
        if self.velocity_spread == 0.0 {
            return vec![1.0; tree.nodes.len()];
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x7e10c1);
        (0..tree.nodes.len()).map(|_| (-self.velocity_spread * standard_normal(&mut rng)).exp()).collect()
    }
}

/// Per node, the path (mm) from its root along the tree, each segment's length times its
/// `slowness`: the contrast reaches the node when it would have travelled that far at the
/// nominal velocity.
fn path_lengths(tree: &VesselTree, slowness: &[f64]) -> Vec<f64> {
    let children = tree.children();
    let mut length = vec![0.0; tree.nodes.len()];
    let mut stack: Vec<usize> = (0..tree.nodes.len()).filter(|&i| tree.nodes[i].parent.is_none()).collect();
    while let Some(i) = stack.pop() {
        for &c in &children[i] {
            length[c] = length[i] + tree.nodes[c].position_mm.distance(tree.nodes[i].position_mm) * slowness[c];
            stack.push(c);
        }
    }
    length
}

/// The arrival map of the `index`-th view `view` (its detector's size; frames, [`NO_ARRIVAL`]
/// where no vessel fills): every segment sampled every 0.1 mm, each point's frame written, where
/// that is earlier, to every pixel whose centre lies within the vessel's projected radius of the
/// point's projection (the pixel it projects into always, so a sub-pixel vessel still fills
/// one): a vessel fills its whole projected width, and hides a later one behind it there. Odd
/// views' frames are `spec.interleave_frames` late; then each filled pixel's frame is moved by
/// its error (`spec.frame_noise`).
pub fn arrival_map(tree: &VesselTree, view: &ConeBeamView, index: usize, spec: &ArrivalSpec) -> Image {
    let (w, h) = (view.width(), view.height());
    let mut first = vec![f32::INFINITY; (w * h) as usize];
    let slowness = spec.slowness(tree);
    let length = path_lengths(tree, &slowness);
    let delay = spec.delay_frames(index);
    let focal_px = view.intrinsics().focal_px[0].abs().max(view.intrinsics().focal_px[1].abs());
    for s in tree.segments() {
        let parent = tree.nodes[s.child].parent.unwrap_or(s.child);
        let (start, span) = (length[parent], s.length_mm() * slowness[s.child]);
        let n = (s.length_mm() / SAMPLE_MM).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = (k as f64 + 0.5) / n as f64;
            let p = s.start_mm.lerp(s.end_mm, t);
            let Some(uv) = view.project(p) else { continue };
            let radius_px = focal_px * (s.start_radius_mm + t * (s.end_radius_mm - s.start_radius_mm)).max(0.0)
                / view.to_camera(p).z;
            let frame = spec.frame(start + t * span, delay);
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
    if spec.frame_noise > 0.0 {
        let mut rng = ChaCha8Rng::seed_from_u64(spec.seed ^ (0xa221_u64 << 16) ^ index as u64);
        for f in first.iter_mut().filter(|f| f.is_finite()) {
            *f = (*f as f64 + (spec.frame_noise * standard_normal(&mut rng)).round()).max(0.0) as f32;
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
        let map = arrival_map(&tree, &view, 0, &ArrivalSpec::ideal(10.0, 100.0));
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
        let map = arrival_map(&tree, &view, 0, &ArrivalSpec::ideal(10.0, 100.0));
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

    /// A straight vessel of 20 segments of 2 mm along z (-20 to 20 mm) from its root, of radius
    /// `radius_mm`, seen whole by [`small_view`].
    fn long_vessel(radius_mm: f64) -> VesselTree {
        let nodes = (0..=20usize)
            .map(|i| wide_node(i as i64 + 1, i.checked_sub(1), [0.0, 0.0, -20.0 + 2.0 * i as f64], radius_mm))
            .collect();
        VesselTree { nodes }
    }

    /// The frames along the vessel's axis (root first; 0.5 mm steps).
    fn along_axis(map: &Image, view: &ConeBeamView) -> Vec<f32> {
        (0..80)
            .map(|k| {
                let uv = view.project(DVec3::new(0.0, 0.0, -19.75 + 0.5 * k as f64)).unwrap();
                map.data[uv.y.round() as usize * 64 + uv.x.round() as usize]
            })
            .collect()
    }

    /// 10 frames/s at 20 mm/s: a frame per 2 mm, frames 0 to 19 along [`long_vessel`].
    const IDEAL: ArrivalSpec = ArrivalSpec::ideal(10.0, 20.0);

    /// Velocities that differ between segments change the frames, never their order along a
    /// vessel (the contrast still arrives later farther from the root), and the same seed draws
    /// the same map.
    #[test]
    fn a_velocity_spread_keeps_the_frames_in_order_and_is_reproducible() {
        let (tree, view) = (long_vessel(0.5), small_view());
        let ideal = IDEAL;
        let spread = |seed| ArrivalSpec { velocity_spread: 0.5, seed, ..ideal };
        let base = arrival_map(&tree, &view, 0, &ideal);
        let first = arrival_map(&tree, &view, 0, &spread(3));
        assert_eq!(first.data, arrival_map(&tree, &view, 0, &spread(3)).data, "same seed, same map");
        assert_ne!(first.data, arrival_map(&tree, &view, 0, &spread(4)).data, "another seed, another map");
        assert_ne!(first.data, base.data, "the spread changes the frames");
        let frames = along_axis(&first, &view);
        assert!(frames.windows(2).all(|w| w[0] <= w[1]), "frames in order along the vessel: {frames:?}");
        // Without the spread the same axis runs frame 0 to 19 (40 mm at 2 mm per frame).
        let ideal_frames = along_axis(&base, &view);
        assert_eq!((ideal_frames[0], ideal_frames[79]), (0.0, 19.0));
    }

    /// Frame errors of σ = 0.5 frames move about a third of the filled pixels (|N(0,1)| ≥ 1:
    /// 31.7 %) by whole frames, fill no pixel the ideal map leaves empty, and stay ≥ 0.
    #[test]
    fn frame_noise_moves_a_third_of_the_pixels_by_whole_frames() {
        let (tree, view) = (long_vessel(1.5), small_view());
        let ideal = IDEAL;
        let base = arrival_map(&tree, &view, 0, &ideal);
        let noisy = arrival_map(&tree, &view, 0, &ArrivalSpec { frame_noise: 0.5, seed: 1, ..ideal });
        let (mut compared, mut moved) = (0usize, 0usize);
        for (&b, &n) in base.data.iter().zip(&noisy.data) {
            assert_eq!(b == NO_ARRIVAL, n == NO_ARRIVAL, "the filled pixels stay the filled pixels");
            if b == NO_ARRIVAL {
                continue;
            }
            assert!(n >= 0.0 && n.fract() == 0.0, "whole frames, never before the first: {n}");
            // Frames 0 cannot go lower; count the pixels that can move either way.
            if b >= 1.0 {
                compared += 1;
                moved += usize::from(n != b);
            }
        }
        let share = moved as f64 / compared as f64;
        assert!(compared > 200, "enough pixels: {compared}");
        assert!((0.24..=0.40).contains(&share), "{moved} of {compared} moved");
    }

    /// Interleaved planes: the second view's frames are half a frame late (the same frame or the
    /// one before, both somewhere), the first view's are the ideal ones.
    #[test]
    fn the_second_plane_is_half_a_frame_late() {
        let (tree, view) = (long_vessel(0.5), small_view());
        let ideal = IDEAL;
        let interleaved = ArrivalSpec { interleave_frames: 0.5, ..ideal };
        let base = arrival_map(&tree, &view, 0, &ideal);
        assert_eq!(arrival_map(&tree, &view, 0, &interleaved).data, base.data);
        let late = arrival_map(&tree, &view, 1, &interleaved);
        let (mut same, mut before) = (0, 0);
        for (&b, &l) in base.data.iter().zip(&late.data) {
            match b - l {
                _ if b == NO_ARRIVAL => assert_eq!(l, NO_ARRIVAL),
                0.0 => same += 1,
                1.0 => before += 1,
                d => panic!("frame {b} became {l} ({d})"),
            }
        }
        assert!(same > 0 && before > 0, "{same} pixels in the same frame, {before} a frame earlier");
    }

    /// Out-of-range realism settings are refused with the setting named.
    #[test]
    fn realism_settings_out_of_range_name_the_setting() {
        let ideal = ArrivalSpec::ideal(7.5, 300.0);
        assert!(ideal.validate().is_ok());
        for (spec, named) in [
            (ArrivalSpec { velocity_spread: -0.1, ..ideal }, "velocity spread"),
            (ArrivalSpec { frame_noise: f64::NAN, ..ideal }, "frame noise"),
            (ArrivalSpec { interleave_frames: 1.5, ..ideal }, "interleave"),
        ] {
            let err = spec.validate().unwrap_err().to_string();
            assert!(err.contains(named), "{err}");
        }
    }
}
