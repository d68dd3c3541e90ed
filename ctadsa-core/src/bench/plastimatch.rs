//! plastimatch, the peer the voxel projector is checked against: its volume format (MetaImage),
//! its image format (PFM) and its CPU DRR run as a child process.

use std::path::Path;
use std::time::Instant;

use ctadsa_render::TigreGeometry;

use crate::data::volume::Volume;
use crate::error::{CoreError, Result, read_file, write_file};

/// Writes a MetaImage (`.mha`, float, x fastest) of `volume` (world mm, axis-aligned).
pub fn write_mha(path: &Path, volume: &Volume<f32>) -> Result<()> {
    let g = volume.grid;
    let [nx, ny, nz] = g.dims;
    let centre0 = g.centre_mm(0, 0, 0);
    let mut bytes = format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
         TransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = {} {} {}\nElementSpacing = {} {} {}\n\
         DimSize = {nx} {ny} {nz}\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n",
        centre0.x, centre0.y, centre0.z, g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]
    )
    .into_bytes();
    bytes.reserve(4 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                bytes.extend(volume.data[g.index(i, j, k)].to_le_bytes());
            }
        }
    }
    write_file(path, &bytes)
}

/// Reads a greyscale PFM image (float; plastimatch writes rows top to bottom): `(width, height,
/// values)`, row-major. Errors name the file.
pub fn read_pfm(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let bytes = read_file(path)?;
    let bad = |what: String| CoreError::format(path, what);
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while at < bytes.len() && bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        if start == at {
            return Err(bad("PFM header cut short".into()));
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).to_string());
    }
    at += 1;
    if fields[0] != "Pf" {
        return Err(bad(format!("not a greyscale PFM (`{}`)", fields[0])));
    }
    let number = |s: &str| s.parse::<usize>().map_err(|_| bad(format!("PFM size `{s}` is not a number")));
    let (w, h) = (number(&fields[1])?, number(&fields[2])?);
    let scale: f64 = fields[3].parse().map_err(|_| bad(format!("PFM scale `{}` is not a number", fields[3])))?;
    let need = w.checked_mul(h).and_then(|n| n.checked_mul(4));
    if need.is_none_or(|n| at.saturating_add(n) > bytes.len()) {
        return Err(bad(format!(
            "{w} × {h} floats need more than the {} bytes after the header",
            bytes.len() - at.min(bytes.len())
        )));
    }
    let little = scale < 0.0;
    let data = bytes[at..at + 4 * w * h]
        .chunks_exact(4)
        .map(|b| {
            let b = [b[0], b[1], b[2], b[3]];
            if little { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) }
        })
        .collect();
    Ok((w, h, data))
}

/// Whether `plastimatch` runs on this machine.
pub fn plastimatch_installed() -> bool {
    std::process::Command::new("plastimatch").arg("--version").output().is_ok()
}

/// Runs plastimatch's CPU DRR of `mha` for `geom` (secondary angle 0) in the folder `work`;
/// returns the image in value × mm, row 0 at the top, and the wall time (s). `None` when
/// plastimatch is not installed.
pub fn plastimatch_drr(mha: &Path, geom: &TigreGeometry, work: &Path) -> Result<Option<(Vec<f32>, f64)>> {
    if !plastimatch_installed() {
        return Ok(None);
    }
    let a = geom.primary_deg.to_radians();
    let [w, h] = geom.detector_px;
    let prefix = work.join("drr");
    let start = Instant::now();
    let out = std::process::Command::new("plastimatch")
        .arg("drr")
        .args(["-A", "cpu", "-i", "exact", "-P", "none", "-t", "pfm"])
        .args(["--sad", &geom.dso_mm.to_string(), "--sid", &geom.dsd_mm.to_string()])
        .args(["-r", &format!("{h} {w}")])
        .args(["-z", &format!("{} {}", h as f64 * geom.pixel_mm[1], w as f64 * geom.pixel_mm[0])])
        .args(["-n", &format!("{} {} 0", a.cos(), a.sin())])
        .args(["--vup", "0 0 1", "-o", "0 0 0"])
        .arg("-O")
        .arg(&prefix)
        .arg(mha)
        .output()
        .map_err(|e| CoreError::io(mha, e))?;
    let elapsed = start.elapsed().as_secs_f64();
    if !out.status.success() {
        return Err(CoreError::invalid(format!("plastimatch drr failed: {}", String::from_utf8_lossy(&out.stderr))));
    }
    let pfm = std::fs::read_dir(work)
        .map_err(|e| CoreError::io(work, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "pfm"))
        .ok_or_else(|| CoreError::format(work, "plastimatch wrote no .pfm"))?;
    let (pw, ph, mut data) = read_pfm(&pfm)?;
    std::fs::remove_file(&pfm).ok();
    if (pw, ph) != (w as usize, h as usize) {
        return Err(CoreError::format(&pfm, format!("plastimatch image is {pw} × {ph}, expected {w} × {h}")));
    }
    // plastimatch integrates in cm for per-mm values: × 10 gives value × mm.
    data.iter_mut().for_each(|v| *v *= 10.0);
    Ok(Some((data, elapsed)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pfm_reads_back_and_short_files_are_refused() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("a.pfm");
        let mut bytes = b"Pf\n2 1\n-1.0\n".to_vec();
        bytes.extend(1.5f32.to_le_bytes());
        bytes.extend((-2.0f32).to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(read_pfm(&path).unwrap(), (2, 1, vec![1.5, -2.0]));
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert!(read_pfm(&path).unwrap_err().to_string().contains("a.pfm"));
        std::fs::write(&path, b"Pf\n99999999999 99999999999\n-1\n").unwrap();
        assert!(read_pfm(&path).is_err());
        std::fs::write(&path, b"Pf\n").unwrap();
        assert!(read_pfm(&path).is_err());
    }
}
