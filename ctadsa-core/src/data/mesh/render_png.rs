//! Pictures of meshes: a small software rasteriser (z-buffer, Lambert shading, orthographic
//! camera orbiting the z axis) that draws several coloured meshes into one PNG.

use std::path::Path;

use glam::{DMat3, DVec3};

use super::TriMesh;
use crate::data::case::images::write_rgb_or_grey;
use crate::error::Result;

/// A mesh with its colour (RGB, 0–255).
pub struct Coloured<'a> {
    pub mesh: &'a TriMesh,
    pub rgb: [u8; 3],
}

/// Camera of [`render_meshes`]: azimuth about `z` and elevation (degrees), image size.
#[derive(Debug, Clone, Copy)]
pub struct OrbitView {
    pub azimuth_deg: f64,
    pub elevation_deg: f64,
    pub width: u32,
    pub height: u32,
}

/// Renders the meshes (all framed together) into RGB pixels, white background.
pub fn render_meshes(meshes: &[Coloured], view: &OrbitView) -> Vec<u8> {
    let (w, h) = (view.width as usize, view.height as usize);
    let mut rgb = vec![255u8; w * h * 3];
    let mut depth = vec![f64::INFINITY; w * h];
    let (az, el) = (view.azimuth_deg.to_radians(), view.elevation_deg.to_radians());
    // Camera looks along −forward; image x = right, image y = up (rows go down).
    let forward = DVec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
    let right = DVec3::Z.cross(forward).normalize_or(DVec3::X);
    let up = forward.cross(right);
    let cam = DMat3::from_cols(right, up, forward).transpose();
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for m in meshes {
        for v in &m.mesh.vertices {
            let p = cam * *v;
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    if !lo.is_finite() {
        return rgb;
    }
    let centre = (lo + hi) / 2.0;
    let span = (hi.x - lo.x).max(hi.y - lo.y).max(1e-9) * 1.08;
    let scale = (w.min(h) as f64) / span;
    let light = (forward + 0.5 * up + 0.3 * right).normalize();
    for m in meshes {
        let pts: Vec<DVec3> = m
            .mesh
            .vertices
            .iter()
            .map(|v| {
                let p = cam * *v - centre;
                DVec3::new(w as f64 / 2.0 + p.x * scale, h as f64 / 2.0 - p.y * scale, -p.z)
            })
            .collect();
        for f in &m.mesh.faces {
            let [a, b, c] = f.map(|i| pts[i as usize]);
            let [wa, wb, wc] = f.map(|i| m.mesh.vertices[i as usize]);
            let n = (wb - wa).cross(wc - wa).normalize_or_zero();
            let shade = 0.25 + 0.75 * n.dot(light).abs();
            let colour = m.rgb.map(|ch| (ch as f64 * shade).round().clamp(0.0, 255.0) as u8);
            let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
            if area.abs() < 1e-12 {
                continue;
            }
            let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as usize;
            let x1 = (a.x.max(b.x).max(c.x).ceil() as usize).min(w.saturating_sub(1));
            let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as usize;
            let y1 = (a.y.max(b.y).max(c.y).ceil() as usize).min(h.saturating_sub(1));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                    let w0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) / area;
                    let w1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = w0 * a.z + w1 * b.z + w2 * c.z;
                    let i = y * w + x;
                    if z < depth[i] {
                        depth[i] = z;
                        rgb[3 * i..3 * i + 3].copy_from_slice(&colour);
                    }
                }
            }
        }
    }
    rgb
}

/// Renders the meshes from `views.len()` orbit views side by side into one PNG.
pub fn write_mesh_png(path: &Path, meshes: &[Coloured], views: &[OrbitView]) -> Result<()> {
    let h = views.iter().map(|v| v.height).max().unwrap_or(1);
    let w: u32 = views.iter().map(|v| v.width).sum();
    let mut out = vec![255u8; (w * h * 3) as usize];
    let mut x_off = 0usize;
    for v in views {
        let tile = render_meshes(meshes, v);
        for row in 0..v.height as usize {
            let src = &tile[row * v.width as usize * 3..(row + 1) * v.width as usize * 3];
            let dst = (row * w as usize + x_off) * 3;
            out[dst..dst + src.len()].copy_from_slice(src);
        }
        x_off += v.width as usize;
    }
    write_rgb_or_grey(path, w, h, out, 3)
}

/// Three standard views (frontal, lateral, oblique from above) of `size` pixels.
pub fn standard_views(size: u32) -> Vec<OrbitView> {
    [(-90.0, 10.0), (0.0, 10.0), (-45.0, 40.0)]
        .iter()
        .map(|&(azimuth_deg, elevation_deg)| OrbitView { azimuth_deg, elevation_deg, width: size, height: size })
        .collect()
}
