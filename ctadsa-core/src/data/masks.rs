//! Binary masks of the views: the vessel mask of a DSA image (a fraction of its bright
//! percentile) and the silhouette of a solid volume (e.g. the prior) in each view.

use ctadsa_render::ConeBeamView;

use crate::data::case::images::Image;
use crate::data::mesh::TriMesh;
use crate::data::mesh::voxelize::voxelize_mesh;
use crate::data::projector::project_volume;
use crate::data::volume::{Grid, Volume};
use crate::stats::percentile;

/// A binary image mask (row-major).
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    pub width: u32,
    pub height: u32,
    pub data: Vec<bool>,
}

impl Mask {
    /// Square dilation by `r` pixels (separable max filter).
    pub fn dilated(&self, r: u32) -> Mask {
        if r == 0 {
            return self.clone();
        }
        let (w, h, r) = (self.width as usize, self.height as usize, r as usize);
        let mut tmp = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
                tmp[y * w + x] = self.data[y * w + x0..=y * w + x1].iter().any(|&b| b);
            }
        }
        let mut out = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
                out[y * w + x] = (y0..=y1).any(|yy| tmp[yy * w + x]);
            }
        }
        Mask { width: self.width, height: self.height, data: out }
    }

    /// Pixels set in `self` and not in `other`.
    pub fn minus(&self, other: &Mask) -> Mask {
        Mask { data: self.data.iter().zip(&other.data).map(|(&a, &b)| a && !b).collect(), ..self.clone() }
    }

    /// Pixels set in both.
    pub fn and(&self, other: &Mask) -> Mask {
        Mask { data: self.data.iter().zip(&other.data).map(|(&a, &b)| a && b).collect(), ..self.clone() }
    }

    /// Number of set pixels.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }
}

/// The image value that defines "vessel": `threshold ×` the 99.5th percentile of the positive
/// pixels (0 for an image without positive pixels).
pub fn vessel_level(image: &Image, threshold: f64) -> f64 {
    let pos: Vec<f64> = image.data.iter().filter(|&&v| v > 0.0).map(|&v| v as f64).collect();
    if pos.is_empty() { 0.0 } else { threshold * percentile(&pos, 99.5) }
}

/// Vessel mask of an image.
pub fn vessel_mask(image: &Image, threshold: f64) -> Mask {
    let level = vessel_level(image, threshold);
    Mask {
        width: image.width,
        height: image.height,
        data: image.data.iter().map(|&v| v as f64 > level && v > 0.0).collect(),
    }
}

/// The prior as solid voxels on `grid`.
pub fn prior_solid(prior: &TriMesh, grid: Grid) -> Volume<u8> {
    voxelize_mesh(prior, grid)
}

/// Silhouette of a solid volume in each view (pixels whose ray crosses it).
pub fn silhouettes(solid: &Volume<u8>, views: &[ConeBeamView]) -> Vec<Mask> {
    let f = solid.map(|v| v as f32);
    project_volume(&f, views)
        .into_iter()
        .zip(views)
        .map(|(img, v)| Mask { width: v.width(), height: v.height(), data: img.iter().map(|&x| x > 0.0).collect() })
        .collect()
}
