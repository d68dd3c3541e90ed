//! NIfTI-1 volumes (`.nii`, `.nii.gz`) through the `nifti` crate.
//!
//! Reading keeps the file's voxel-to-world affine (sform if set, else qform, else the voxel
//! sizes) so meshes extracted from a label volume land in the file's world millimetres.
//! Writing stores our axis-aligned grid as both sform and qform.

use std::path::Path;

use glam::{DMat4, DVec4};
use ndarray::Array3;
use nifti::{IntoNdArray, NiftiHeader, NiftiObject, ReaderOptions, writer::WriterOptions};

use super::{Grid, Volume};
use crate::error::{CoreError, Result, write_through_temporary};

/// NIfTI datatype codes of scalar voxels (u8, i16, i32, f32, f64, i8, u16, u32, i64, u64).
const SCALAR_DATATYPES: [i16; 10] = [2, 4, 8, 16, 64, 256, 512, 768, 1024, 1280];

/// Checks the header fields this reader relies on before any voxel is read; the error names
/// the field.
fn check_header(path: &Path, h: &NiftiHeader) -> Result<[usize; 3]> {
    let bad = |field: &str, problem: String| CoreError::format(path, format!("NIfTI header `{field}`: {problem}"));
    if !SCALAR_DATATYPES.contains(&h.datatype) {
        return Err(bad("datatype", format!("{} is not a scalar voxel type this reader takes", h.datatype)));
    }
    let ndim = h.dim[0];
    if !(3..=7).contains(&ndim) {
        return Err(bad("dim[0]", format!("{ndim} dimensions; expected a 3-D volume")));
    }
    let dims = &h.dim[1..=ndim as usize];
    if dims.iter().any(|&d| d < 1) || dims[3..].iter().any(|&d| d != 1) {
        return Err(bad("dim", format!("{dims:?}; expected a 3-D volume of at least one voxel per axis")));
    }
    let n = [dims[0], dims[1], dims[2]].map(|d| d as usize);
    let total = n.iter().map(|&d| d as f64).product::<f64>();
    if total > super::MAX_GRID_VOXELS as f64 {
        return Err(bad("dim", format!("{n:?} is {total:.2e} voxels, more than {}", super::MAX_GRID_VOXELS)));
    }
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if h.sform_code > 0 {
        if !(finite(&h.srow_x) && finite(&h.srow_y) && finite(&h.srow_z)) {
            return Err(bad("srow_x/y/z", "not finite".into()));
        }
    } else {
        if !h.pixdim[1..4].iter().all(|v| v.is_finite() && *v != 0.0) {
            return Err(bad("pixdim", format!("voxel sizes {:?} must be finite and non-zero", &h.pixdim[1..4])));
        }
        if h.qform_code > 0 {
            let q = [h.quatern_b, h.quatern_c, h.quatern_d];
            let norm2: f32 = q.iter().map(|v| v * v).sum();
            if !finite(&q) || !finite(&[h.quatern_x, h.quatern_y, h.quatern_z]) || norm2 > 1.0 + 1e-4 {
                return Err(bad(
                    "quatern_b/c/d",
                    format!("{q:?} is not the vector part of a unit quaternion (b² + c² + d² = {norm2})"),
                ));
            }
        }
    }
    Ok(n)
}

fn header_affine(h: &NiftiHeader) -> DMat4 {
    let row = |r: [f32; 4]| DVec4::new(r[0] as f64, r[1] as f64, r[2] as f64, r[3] as f64);
    if h.sform_code > 0 {
        let (x, y, z) = (row(h.srow_x), row(h.srow_y), row(h.srow_z));
        return DMat4::from_cols(
            DVec4::new(x.x, y.x, z.x, 0.0),
            DVec4::new(x.y, y.y, z.y, 0.0),
            DVec4::new(x.z, y.z, z.z, 0.0),
            DVec4::new(x.w, y.w, z.w, 1.0),
        );
    }
    let p = h.pixdim.map(|v| v as f64);
    let (dx, dy, dz) = (p[1].abs().max(1e-12), p[2].abs().max(1e-12), p[3].abs().max(1e-12));
    if h.qform_code > 0 {
        let (b, c, d) = (h.quatern_b as f64, h.quatern_c as f64, h.quatern_d as f64);
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let qfac = if p[0] < 0.0 { -1.0 } else { 1.0 };
        let r = glam::DMat3::from_cols(
            glam::DVec3::new(a * a + b * b - c * c - d * d, 2.0 * (b * c + a * d), 2.0 * (b * d - a * c)),
            glam::DVec3::new(2.0 * (b * c - a * d), a * a + c * c - b * b - d * d, 2.0 * (c * d + a * b)),
            glam::DVec3::new(2.0 * (b * d + a * c), 2.0 * (c * d - a * b), a * a + d * d - c * c - b * b),
        );
        let s = glam::DMat3::from_diagonal(glam::DVec3::new(dx, dy, dz * qfac));
        let m = r * s;
        return DMat4::from_cols(
            m.x_axis.extend(0.0),
            m.y_axis.extend(0.0),
            m.z_axis.extend(0.0),
            DVec4::new(h.quatern_x as f64, h.quatern_y as f64, h.quatern_z as f64, 1.0),
        );
    }
    DMat4::from_diagonal(DVec4::new(dx, dy, dz, 1.0))
}

/// Reads a 3-D NIfTI volume as f32 (scaled by `scl_slope`/`scl_inter` as the file says).
pub fn read_nifti(path: &Path) -> Result<Volume<f32>> {
    crate::error::check_input_file(path)?;
    let header = NiftiHeader::from_file(path)
        .map_err(|e| CoreError::format(path, format!("not a readable NIfTI-1 header: {e}")))?;
    let dims = check_header(path, &header)?;
    let obj = ReaderOptions::new()
        .read_file(path)
        .map_err(|e| CoreError::format(path, format!("not a readable NIfTI-1 file: {e}")))?;
    let header = obj.header().clone();
    let array = obj
        .into_volume()
        .into_ndarray::<f32>()
        .map_err(|e| CoreError::format(path, format!("cannot read voxel data: {e}")))?;
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    if array.shape().iter().product::<usize>() != nx * ny * nz || array.ndim() < 3 {
        return Err(CoreError::format(path, format!("voxel array has shape {:?}", array.shape())));
    }
    let mut index = vec![0usize; array.ndim()];
    let mut data = Vec::with_capacity(nx * ny * nz);
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                index[0] = i;
                index[1] = j;
                index[2] = k;
                data.push(array[ndarray::IxDyn(&index)]);
            }
        }
    }
    if data.iter().any(|v| !v.is_finite()) {
        return Err(CoreError::format(path, "volume contains NaN or infinite voxels"));
    }
    let affine = header_affine(&header);
    let spacing_mm = [0, 1, 2].map(|a| affine.col(a).truncate().length());
    if spacing_mm.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(CoreError::format(path, format!("degenerate voxel size {spacing_mm:?}")));
    }
    let t = affine.col(3).truncate();
    let grid = Grid { dims: [nx, ny, nz], spacing_mm, origin_mm: [0, 1, 2].map(|a| t[a] - 0.5 * spacing_mm[a]) };
    Ok(Volume { grid, index_to_world: affine, data })
}

fn header_for(grid: &Grid, index_to_world: &DMat4, description: &str) -> NiftiHeader {
    let m = index_to_world;
    let row = |r: usize| [m.col(0)[r] as f32, m.col(1)[r] as f32, m.col(2)[r] as f32, m.col(3)[r] as f32];
    let mut h = NiftiHeader {
        pixdim: [
            1.0,
            grid.spacing_mm[0] as f32,
            grid.spacing_mm[1] as f32,
            grid.spacing_mm[2] as f32,
            1.0,
            1.0,
            1.0,
            1.0,
        ],
        sform_code: 2,
        srow_x: row(0),
        srow_y: row(1),
        srow_z: row(2),
        xyzt_units: 2, // millimetres
        ..NiftiHeader::default()
    };
    let diagonal = (0..3).all(|c| (0..3).all(|r| r == c || m.col(c)[r] == 0.0));
    if diagonal && (0..3).all(|a| m.col(a)[a] > 0.0) {
        h.qform_code = 2;
        h.quatern_x = m.col(3)[0] as f32;
        h.quatern_y = m.col(3)[1] as f32;
        h.quatern_z = m.col(3)[2] as f32;
    }
    let _ = h.set_description_str(description.chars().take(79).collect::<String>());
    h
}

/// Writes a volume as a single-file NIfTI-1, `.nii` or (gzip-compressed) `.nii.gz`, atomically
/// (a temporary beside it, then renamed).
pub fn write_nifti<T>(path: &Path, volume: &Volume<T>, description: &str) -> Result<()>
where
    T: nifti::DataElement + bytemuck::Pod + Copy,
{
    let name = path.file_name().map(|n| n.to_string_lossy().to_lowercase()).unwrap_or_default();
    // The temporary's name is `.tmp-<unique>.nii[.gz]`: the NIfTI writer picks compression by
    // the ending and replaces the last extension left after stripping one, so no other dots.
    let suffix = if name.ends_with(".nii.gz") {
        "nii.gz"
    } else if name.ends_with(".nii") {
        "nii"
    } else {
        return Err(CoreError::format(path, "a NIfTI volume is written as .nii or .nii.gz".to_string()));
    };
    let [nx, ny, nz] = volume.grid.dims;
    let array = Array3::from_shape_vec((nx, ny, nz), volume.data.clone())
        .map_err(|e| CoreError::invalid(format!("volume data does not match its grid: {e}")))?;
    let header = header_for(&volume.grid, &volume.index_to_world, description);
    write_through_temporary(path, suffix, |tmp| {
        WriterOptions::new(tmp)
            .reference_header(&header)
            .write_nifti(&array)
            .map_err(|e| CoreError::format(path, format!("cannot write NIfTI: {e}")))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_and_geometry() {
        let grid = Grid { dims: [4, 3, 5], spacing_mm: [0.5, 0.7, 1.1], origin_mm: [-1.0, 2.0, 3.0] };
        let mut v = Volume::<f32>::zeros(grid);
        for (i, x) in v.data.iter_mut().enumerate() {
            *x = i as f32 * 0.25;
        }
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("v.nii.gz");
        write_nifti(&path, &v, "test").unwrap();
        let back = read_nifti(&path).unwrap();
        assert_eq!(back.data, v.data);
        assert_eq!(back.grid.dims, grid.dims);
        for a in 0..3 {
            assert!((back.grid.spacing_mm[a] - grid.spacing_mm[a]).abs() < 1e-6);
            assert!((back.grid.origin_mm[a] - grid.origin_mm[a]).abs() < 1e-5);
        }
        let gz = std::fs::read(&path).unwrap();
        assert_eq!(gz[..2], [0x1f, 0x8b], "compressed as its name says");
        // A name with more dots (the NIfTI writer alone wrote `v.b.nii` to `v.nii`).
        write_nifti(&dir.join("v.b.nii"), &v, "test").unwrap();
        assert_eq!(read_nifti(&dir.join("v.b.nii")).unwrap().data, v.data);
        let err = write_nifti(&dir.join("v.hdr"), &v, "test").unwrap_err().to_string();
        assert!(err.contains("v.hdr") && err.contains(".nii.gz"), "{err}");
        let mut names: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        names.sort();
        assert_eq!(names, ["v.b.nii", "v.nii.gz"], "no temporary, pair or renamed file left");
    }

    #[test]
    fn garbage_is_a_named_error() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let path = dir.join("bad.nii");
        std::fs::write(&path, b"not a nifti file at all").unwrap();
        let err = read_nifti(&path).unwrap_err().to_string();
        assert!(err.contains("bad.nii"), "{err}");
        let missing = read_nifti(&dir.join("missing.nii.gz")).unwrap_err().to_string();
        assert!(missing.contains("missing.nii.gz"), "{missing}");
    }
}
