//! View and geometry presets of synthetic cases.

use ctadsa_render::TigreGeometry;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, Result};

/// Detector/C-arm geometry presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GeometryPreset {
    /// The paper's synthetic geometry: DSD 700 mm, DSO 500 mm, 512 × 512 pixels of 0.5 mm.
    Reference,
    /// A clinical C-arm: DSD 1200 mm, DSO 800 mm, 1024 × 1024 pixels of 0.2 mm.
    CArm,
}

impl GeometryPreset {
    /// Parses `reference` or `c-arm`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "reference" => Ok(Self::Reference),
            "c-arm" => Ok(Self::CArm),
            other => Err(CoreError::invalid(format!("unknown geometry preset `{other}` (reference, c-arm)"))),
        }
    }

    /// The geometry at primary/secondary angles (degrees), detector binned by `binning`.
    pub fn geometry(&self, primary_deg: f64, secondary_deg: f64, binning: u32) -> TigreGeometry {
        let (dsd_mm, dso_mm, n, pitch) = match self {
            Self::Reference => (700.0, 500.0, 512u32, 0.5),
            Self::CArm => (1200.0, 800.0, 1024u32, 0.2),
        };
        let b = binning.max(1);
        TigreGeometry {
            dsd_mm,
            dso_mm,
            detector_px: [n / b, n / b],
            pixel_mm: [pitch * b as f64, pitch * b as f64],
            offset_mm: [0.0, 0.0],
            primary_deg,
            secondary_deg,
        }
    }
}

/// A named view: `(name, primary angle, secondary angle)` in degrees.
pub type NamedAngle = (String, f64, f64);

/// The view sets: `ap-lat` (−90°, 0°), `ap-lat-oblique` (−90°, 0°, −45°), or an explicit list
/// `angles:P[/S],P[/S],…` (primary/secondary degrees).
pub fn view_preset(spec: &str) -> Result<Vec<NamedAngle>> {
    let named = |n: &str, p: f64| (n.to_string(), p, 0.0);
    match spec {
        "ap-lat" => Ok(vec![named("ap", -90.0), named("lat", 0.0)]),
        "ap-lat-oblique" => Ok(vec![named("ap", -90.0), named("lat", 0.0), named("oblique", -45.0)]),
        other => {
            let list = other.strip_prefix("angles:").ok_or_else(|| {
                CoreError::invalid(format!(
                    "unknown view preset `{other}` (ap-lat, ap-lat-oblique, or angles:-90,0,-45/10)"
                ))
            })?;
            let views = list
                .split(',')
                .enumerate()
                .map(|(i, item)| {
                    let mut parts = item.split('/');
                    let p = parts.next().unwrap_or("").trim().parse::<f64>();
                    let s = parts.next().map(|s| s.trim().parse::<f64>()).transpose();
                    match (p, s, parts.next()) {
                        (Ok(p), Ok(s), None)
                            if (-360.0..=360.0).contains(&p) && s.is_none_or(|s| (-90.0..=90.0).contains(&s)) =>
                        {
                            Ok((format!("view{i}"), p, s.unwrap_or(0.0)))
                        }
                        _ => Err(CoreError::invalid(format!(
                            "bad angle `{item}` in `{other}`: primary in −360..360°, secondary in −90..90°"
                        ))),
                    }
                })
                .collect::<Result<Vec<NamedAngle>>>()?;
            // The same direction twice would pass one view's pixels off as a second direction.
            for (k, (_, p, s)) in views.iter().enumerate() {
                if views[..k].iter().any(|(_, q, t)| (p - q).rem_euclid(360.0) == 0.0 && s == t) {
                    return Err(CoreError::invalid(format!("`{other}` names the direction {p}/{s}° twice")));
                }
            }
            Ok(views)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets() {
        assert_eq!(view_preset("ap-lat").unwrap().len(), 2);
        let v = view_preset("angles:-90,0/15,30").unwrap();
        assert_eq!(v[1], ("view1".to_string(), 0.0, 15.0));
        assert!(view_preset("angles:x").is_err());
        for bad in ["angles:1e300", "angles:0/nan", "angles:0/100", "angles:0/1/2", "angles:0,360", "angles:-90,0,-90"]
        {
            assert!(view_preset(bad).is_err(), "{bad} accepted");
        }
        assert!(view_preset("nope").is_err());
        let g = GeometryPreset::CArm.geometry(0.0, 0.0, 2);
        assert_eq!(g.detector_px, [512, 512]);
        assert_eq!(g.pixel_mm, [0.4, 0.4]);
    }
}
