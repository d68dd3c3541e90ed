//! The Gaussian parameters of a scene, as burn tensors.

use burn::tensor::{Tensor, TensorData};

use crate::RenderError;

/// The Gaussian parameters of a scene, `N` Gaussians.
#[derive(Debug, Clone)]
pub struct Gaussians {
    /// Centres `[N, 3]` (mm, world).
    pub means: Tensor<2>,
    /// Standard deviations along the local axes `[N, 3]` (mm, > 0).
    pub scales: Tensor<2>,
    /// Rotations `[N, 4]` as quaternions `(w, x, y, z)`; normalised inside the op.
    pub rotations: Tensor<2>,
    /// Central densities `[N]` (per mm: a pixel value is density × mm).
    pub densities: Tensor<1>,
}

impl Gaussians {
    /// Number of Gaussians `N`, after checking that the four tensors agree in shape.
    pub fn check_shapes(&self) -> Result<usize, RenderError> {
        let n = self.densities.dims()[0];
        let expect = |name: &'static str, got: Vec<usize>, cols: usize| {
            if got == [n, cols] {
                Ok(())
            } else {
                Err(RenderError::Shape { name, expected: format!("[{n}, {cols}]"), got })
            }
        };
        expect("means", self.means.dims().to_vec(), 3)?;
        expect("scales", self.scales.dims().to_vec(), 3)?;
        expect("rotations", self.rotations.dims().to_vec(), 4)?;
        Ok(n)
    }

    /// Reads the parameters back (a device sync) and reports the first Gaussian with a
    /// non-finite value, a non-positive scale, a negative density or a zero quaternion.
    /// The kernels themselves skip such Gaussians, so this is for reporting, not safety.
    pub fn validate(&self) -> Result<(), RenderError> {
        let n = self.check_shapes()?;
        let read = |t: TensorData| -> Result<Vec<f32>, RenderError> {
            t.convert::<f32>().try_to_vec::<f32>().map_err(|e| RenderError::Readback(format!("{e:?}")))
        };
        let means = read(self.means.clone().into_data())?;
        let scales = read(self.scales.clone().into_data())?;
        let rotations = read(self.rotations.clone().into_data())?;
        let densities = read(self.densities.clone().into_data())?;
        for i in 0..n {
            let bad = |problem: String| Err(RenderError::InvalidGaussian { index: i, problem });
            let m = &means[3 * i..3 * i + 3];
            let s = &scales[3 * i..3 * i + 3];
            let q = &rotations[4 * i..4 * i + 4];
            if !m.iter().all(|v| v.is_finite()) {
                return bad(format!("non-finite mean {m:?}"));
            }
            if !s.iter().all(|v| v.is_finite() && *v > 0.0) {
                return bad(format!("scales must be positive and finite, got {s:?}"));
            }
            if !q.iter().all(|v| v.is_finite()) || q.iter().map(|v| v * v).sum::<f32>() < 1e-24 {
                return bad(format!("quaternion must be finite and non-zero, got {q:?}"));
            }
            let d = densities[i];
            if !(d.is_finite() && d >= 0.0) {
                return bad(format!("density must be finite and ≥ 0, got {d}"));
            }
        }
        Ok(())
    }
}
