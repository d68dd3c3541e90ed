//! A view packed as f32 numbers for the kernels.

use crate::geometry::ConeBeamView;

/// Number of f32 values of one packed view (see [`ViewParams::to_array`]).
pub const VIEW_PARAMS_LEN: usize = 20;

/// One view as the kernels use it: camera-frame point `t = R x + T` (mm), pinhole intrinsics (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewParams {
    /// World-to-camera rotation, row-major.
    pub rotation: [f32; 9],
    /// Camera translation `T = −R S` (mm).
    pub translation: [f32; 3],
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// `1/f_x`, `1/f_y`.
    pub inv_fx: f32,
    pub inv_fy: f32,
    pub width: u32,
    pub height: u32,
}

impl ViewParams {
    /// Packs a view (f64 geometry rounded to f32).
    pub fn new(view: &ConeBeamView) -> Self {
        let r = view.rotation();
        let t = -(r * view.source_mm());
        let intr = view.intrinsics();
        // glam stores columns: row i of R is (col0[i], col1[i], col2[i]).
        let rows = r.transpose().to_cols_array();
        Self {
            rotation: rows.map(|v| v as f32),
            translation: [t.x as f32, t.y as f32, t.z as f32],
            fx: intr.focal_px[0] as f32,
            fy: intr.focal_px[1] as f32,
            cx: intr.principal_px[0] as f32,
            cy: intr.principal_px[1] as f32,
            inv_fx: (1.0 / intr.focal_px[0]) as f32,
            inv_fy: (1.0 / intr.focal_px[1]) as f32,
            width: view.width(),
            height: view.height(),
        }
    }

    /// The packed layout used by the GPU kernels:
    /// `[R (9, row-major), T (3), fx, fy, cx, cy, 1/fx, 1/fy, width, height]`.
    pub fn to_array(&self) -> [f32; VIEW_PARAMS_LEN] {
        let mut a = [0.0; VIEW_PARAMS_LEN];
        a[..9].copy_from_slice(&self.rotation);
        a[9..12].copy_from_slice(&self.translation);
        a[12..].copy_from_slice(&[
            self.fx,
            self.fy,
            self.cx,
            self.cy,
            self.inv_fx,
            self.inv_fy,
            self.width as f32,
            self.height as f32,
        ]);
        a
    }
}
