//! Cone-beam view geometry: where the X-ray source is and which ray each detector pixel sees.
//!
//! World coordinates are millimetres with the isocentre at the origin. A view is a pinhole camera
//! whose centre is the X-ray source and whose image plane is the detector:
//! a world point `x` has camera coordinates `t = R (x − S)` (rows of `R` are the camera axes in
//! world coordinates, `S` the source) and lands on pixel
//! `u = f_x t_x / t_z + c_x`, `v = f_y t_y / t_z + c_y`, with pixel centres at integer indices,
//! column `u` to the right and row `v = 0` at the top of the image.
//!
//! [`TigreGeometry`] builds such a view from C-arm parameters exactly as TIGRE (and the
//! R²-Gaussian / reference code, which flip TIGRE's rows so that row 0 is at the top) defines them:
//! with primary angle α and secondary angle β = 0 the source sits at `DSO·(cos α, sin α, 0)`,
//! the detector centre at `−(DSD − DSO)·(cos α, sin α, 0)`, the detector `u` axis is
//! `(−sin α, cos α, 0)` and image row 0 is at `+z`. AP is α = −90°, LAT is α = 0°.

use glam::{DMat3, DMat4, DVec2, DVec3, DVec4};

use crate::RenderError;

/// C-arm parameters in TIGRE's conventions (distances and pixel sizes in mm, angles in degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TigreGeometry {
    /// Source-to-detector distance DSD (mm).
    pub dsd_mm: f64,
    /// Source-to-isocentre distance DSO (mm).
    pub dso_mm: f64,
    /// Detector size in pixels, `[width (u, columns), height (v, rows)]`.
    pub detector_px: [u32; 2],
    /// Detector pixel pitch `[dU, dV]` (mm).
    pub pixel_mm: [f64; 2],
    /// Detector offset `[offU, offV]` (mm): TIGRE's `offDetector` (given there as (V, U)),
    /// the shift of the detector along its `u` axis and along `+z`.
    pub offset_mm: [f64; 2],
    /// Primary (gantry) angle α in degrees: rotation of the source about the world `z` axis.
    pub primary_deg: f64,
    /// Secondary (cranial/caudal) angle β in degrees; tilts the source out of the `z = 0` plane,
    /// following the reference code's `world2cam` (its `s = −β`): the source is at
    /// `DSO·(cos β cos α, cos β sin α, −sin β)`.
    pub secondary_deg: f64,
}

/// Pinhole intrinsics of a detector image, in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    /// Focal lengths `[f_x, f_y]` in pixels (for a flat detector: DSD / pixel pitch).
    pub focal_px: [f64; 2],
    /// Principal point `[c_x, c_y]` in pixels (pixel centres at integer indices).
    pub principal_px: [f64; 2],
}

/// Largest detector side (pixels) a view may have (the CPU forward packs pixel ranges in 16
/// bits; a 65,536² detector would already be 16 GiB per image).
pub const MAX_DETECTOR_PX: u32 = 1 << 16;

/// Largest |angle| (degrees) a C-arm angle may have: beyond a full turn an angle is a unit or
/// field mix-up, not a pose.
pub const MAX_ANGLE_DEG: f64 = 360.0;

/// One cone-beam X-ray view: the source position, the camera rotation and the detector intrinsics.
///
/// Invariants (checked by the constructors): the rotation is orthonormal with determinant +1,
/// focal lengths are positive and finite, and the image has at least one pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConeBeamView {
    rotation: DMat3,
    source_mm: DVec3,
    intrinsics: Intrinsics,
    width: u32,
    height: u32,
}

impl TigreGeometry {
    /// The reference synthetic geometry: DSD 700 mm, DSO 500 mm, 512 × 512 pixels of 0.5 mm.
    pub fn reference(primary_deg: f64) -> Self {
        Self {
            dsd_mm: 700.0,
            dso_mm: 500.0,
            detector_px: [512, 512],
            pixel_mm: [0.5, 0.5],
            offset_mm: [0.0, 0.0],
            primary_deg,
            secondary_deg: 0.0,
        }
    }
}

impl ConeBeamView {
    /// Builds the view of a C-arm described by TIGRE-style parameters.
    pub fn from_tigre(g: &TigreGeometry) -> Result<Self, RenderError> {
        let finite = [
            g.dsd_mm,
            g.dso_mm,
            g.pixel_mm[0],
            g.pixel_mm[1],
            g.offset_mm[0],
            g.offset_mm[1],
            g.primary_deg,
            g.secondary_deg,
        ];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err(RenderError::InvalidView(format!("non-finite TIGRE parameter in {g:?}")));
        }
        if g.primary_deg.abs() > MAX_ANGLE_DEG || g.secondary_deg.abs() > MAX_ANGLE_DEG {
            return Err(RenderError::InvalidView(format!(
                "angles are in degrees within ±360, got primary {}° and secondary {}°",
                g.primary_deg, g.secondary_deg
            )));
        }
        if g.dso_mm <= 0.0 || g.dsd_mm <= g.dso_mm {
            return Err(RenderError::InvalidView(format!(
                "need 0 < DSO < DSD, got DSO {} mm and DSD {} mm",
                g.dso_mm, g.dsd_mm
            )));
        }
        if g.pixel_mm[0] <= 0.0 || g.pixel_mm[1] <= 0.0 {
            return Err(RenderError::InvalidView(format!(
                "detector pixel pitch must be positive, got {:?} mm",
                g.pixel_mm
            )));
        }
        let (p, s) = (g.primary_deg.to_radians(), -g.secondary_deg.to_radians());
        let (sp, cp, ss, cs) = (p.sin(), p.cos(), s.sin(), s.cos());
        // Rows: camera x (detector u), camera y (image down), camera z (towards isocentre).
        let rotation = DMat3::from_cols(
            DVec3::new(-sp, ss * cp, -cs * cp),
            DVec3::new(cp, ss * sp, -cs * sp),
            DVec3::new(0.0, -cs, -ss),
        );
        // t = R x + (0, 0, DSO)  =>  source S = −Rᵀ (0, 0, DSO).
        let source_mm = -(rotation.transpose() * DVec3::new(0.0, 0.0, g.dso_mm));
        let [w, h] = g.detector_px;
        let intrinsics = Intrinsics {
            focal_px: [g.dsd_mm / g.pixel_mm[0], g.dsd_mm / g.pixel_mm[1]],
            principal_px: [
                (w as f64 - 1.0) / 2.0 - g.offset_mm[0] / g.pixel_mm[0],
                (h as f64 - 1.0) / 2.0 + g.offset_mm[1] / g.pixel_mm[1],
            ],
        };
        Self::new(rotation, source_mm, intrinsics, w, h)
    }

    /// Builds a view from a 4 × 4 world-to-camera matrix (what a 2-D/3-D registration gives:
    /// camera `x` along image columns, `y` along image rows, `z` from the source towards the
    /// detector; translation in mm) and pinhole intrinsics in pixels.
    pub fn from_world_to_camera(
        world_to_camera: DMat4,
        intrinsics: Intrinsics,
        width: u32,
        height: u32,
    ) -> Result<Self, RenderError> {
        let m = world_to_camera;
        let last_row = m.row(3);
        if (last_row - DVec4::new(0.0, 0.0, 0.0, 1.0)).abs().max_element() > 1e-9 {
            return Err(RenderError::InvalidView(format!(
                "world-to-camera matrix must have last row (0, 0, 0, 1), got {last_row:?}"
            )));
        }
        let rotation = DMat3::from_mat4(m);
        let translation = m.w_axis.truncate();
        let source_mm = -(rotation.transpose() * translation);
        Self::new(rotation, source_mm, intrinsics, width, height)
    }

    /// Builds a view from its parts: `rotation` (rows = camera axes in world coordinates),
    /// the source position (mm) and intrinsics.
    pub fn new(
        rotation: DMat3,
        source_mm: DVec3,
        intrinsics: Intrinsics,
        width: u32,
        height: u32,
    ) -> Result<Self, RenderError> {
        let ortho = (rotation * rotation.transpose() - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()));
        if !ortho.is_finite() || ortho > 1e-6 || (rotation.determinant() - 1.0).abs() > 1e-6 {
            return Err(RenderError::InvalidView(format!(
                "camera rotation is not a proper rotation (|R Rᵀ − I| = {ortho:e}, det = {})",
                rotation.determinant()
            )));
        }
        if !source_mm.is_finite() {
            return Err(RenderError::InvalidView("non-finite source position".into()));
        }
        let [fx, fy] = intrinsics.focal_px;
        let [cx, cy] = intrinsics.principal_px;
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err(RenderError::InvalidView(format!(
                "focal lengths must be positive and finite, got {:?} px",
                intrinsics.focal_px
            )));
        }
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(RenderError::InvalidView("non-finite principal point".into()));
        }
        if width == 0 || height == 0 || width > MAX_DETECTOR_PX || height > MAX_DETECTOR_PX {
            return Err(RenderError::InvalidView(format!(
                "detector must have 1 to {MAX_DETECTOR_PX} pixels per side, got {width} × {height}"
            )));
        }
        Ok(Self { rotation, source_mm, intrinsics, width, height })
    }

    /// The X-ray source position (mm, world).
    pub fn source_mm(&self) -> DVec3 {
        self.source_mm
    }

    /// World-to-camera rotation; its rows are the camera axes in world coordinates.
    pub fn rotation(&self) -> DMat3 {
        self.rotation
    }

    /// The pinhole intrinsics (pixels).
    pub fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    /// Image width in pixels (columns, `u`).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels (rows, `v`).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The 4 × 4 world-to-camera matrix `[R | −R S]` (mm).
    pub fn world_to_camera(&self) -> DMat4 {
        let t = -(self.rotation * self.source_mm);
        DMat4::from_cols(
            self.rotation.x_axis.extend(0.0),
            self.rotation.y_axis.extend(0.0),
            self.rotation.z_axis.extend(0.0),
            t.extend(1.0),
        )
    }

    /// A world point (mm) in camera coordinates (mm; `z` = depth from the source along the axis).
    pub fn to_camera(&self, world_mm: DVec3) -> DVec3 {
        self.rotation * (world_mm - self.source_mm)
    }

    /// Pixel coordinates `(u, v)` of a world point, or `None` when it is not in front of the source.
    pub fn project(&self, world_mm: DVec3) -> Option<DVec2> {
        let t = self.to_camera(world_mm);
        if t.z <= 0.0 {
            return None;
        }
        let [fx, fy] = self.intrinsics.focal_px;
        let [cx, cy] = self.intrinsics.principal_px;
        Some(DVec2::new(fx * t.x / t.z + cx, fy * t.y / t.z + cy))
    }

    /// Unit direction (world) of the ray from the source through pixel position `(u, v)`.
    pub fn pixel_ray(&self, u: f64, v: f64) -> DVec3 {
        let [fx, fy] = self.intrinsics.focal_px;
        let [cx, cy] = self.intrinsics.principal_px;
        let cam = DVec3::new((u - cx) / fx, (v - cy) / fy, 1.0);
        (self.rotation.transpose() * cam).normalize()
    }

    /// The same view with its pose changed by a rigid motion of the imaging system: `delta`
    /// (a world-frame rotation about the isocentre followed by a translation, mm) is applied to
    /// the source and the camera axes. Used for pose refinement and for perturbation studies.
    pub fn moved(&self, delta_rotation: DMat3, delta_translation_mm: DVec3) -> Result<Self, RenderError> {
        let rotation = self.rotation * delta_rotation.transpose();
        let source_mm = delta_rotation * self.source_mm + delta_translation_mm;
        Self::new(rotation, source_mm, self.intrinsics, self.width, self.height)
    }

    /// Same view on a detector binned by `factor` (image size divided, pixel pitch multiplied).
    /// The field of view is kept: pixel centres of the binned image sit at the centres of the
    /// binned blocks.
    pub fn binned(&self, factor: u32) -> Result<Self, RenderError> {
        if factor == 0 {
            return Err(RenderError::InvalidView("binning factor must be ≥ 1".into()));
        }
        let f = factor as f64;
        let [fx, fy] = self.intrinsics.focal_px;
        let [cx, cy] = self.intrinsics.principal_px;
        let intrinsics =
            Intrinsics { focal_px: [fx / f, fy / f], principal_px: [(cx + 0.5) / f - 0.5, (cy + 0.5) / f - 0.5] };
        Self::new(
            self.rotation,
            self.source_mm,
            intrinsics,
            (self.width / factor).max(1),
            (self.height / factor).max(1),
        )
    }
}
