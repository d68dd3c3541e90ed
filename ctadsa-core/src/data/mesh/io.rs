//! Mesh files: OBJ (read with `tobj`), PLY (ASCII or binary little-endian) and STL (ASCII or
//! binary), chosen by file extension. Coordinates are world mm. Point clouds with named float
//! columns (Gaussians) are written as binary PLY.

use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;

use super::TriMesh;
use crate::error::{CoreError, Result, read_file, write_file};

/// Mesh file formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    Obj,
    Ply,
    Stl,
}

impl MeshFormat {
    /// The format named by a path's extension (case-insensitive).
    pub fn from_path(path: &Path) -> Result<Self> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        match ext.as_str() {
            "obj" => Ok(Self::Obj),
            "ply" => Ok(Self::Ply),
            "stl" => Ok(Self::Stl),
            _ => Err(CoreError::format(path, "unknown mesh extension (use .obj, .ply or .stl)")),
        }
    }
}

/// Reads a triangle mesh (polygons are fan-triangulated). Fails with the file name on a
/// malformed file, an out-of-range index, non-finite coordinates or no triangles.
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    let mesh = match MeshFormat::from_path(path)? {
        MeshFormat::Obj => read_obj(path)?,
        MeshFormat::Ply => parse_ply(&read_file(path)?).map_err(|p| CoreError::format(path, p))?,
        MeshFormat::Stl => parse_stl(&read_file(path)?).map_err(|p| CoreError::format(path, p))?,
    };
    validate(&mesh).map_err(|p| CoreError::format(path, p))?;
    Ok(mesh)
}

fn validate(m: &TriMesh) -> std::result::Result<(), String> {
    if m.faces.is_empty() {
        return Err("mesh has no triangles".into());
    }
    if let Some(i) = m.vertices.iter().position(|v| !v.is_finite()) {
        return Err(format!("vertex {i} is not finite: {}", m.vertices[i]));
    }
    let n = m.vertices.len() as u32;
    if let Some((fi, f)) = m.faces.iter().enumerate().find(|(_, f)| f.iter().any(|&v| v >= n)) {
        return Err(format!("face {fi} {f:?} refers to a vertex beyond the {n} vertices"));
    }
    Ok(())
}

/// Writes a mesh in the format of the path's extension (PLY and STL binary).
pub fn write_mesh(path: &Path, mesh: &TriMesh) -> Result<()> {
    let bytes = match MeshFormat::from_path(path)? {
        MeshFormat::Obj => obj_bytes(mesh),
        MeshFormat::Ply => ply_bytes(mesh),
        MeshFormat::Stl => stl_bytes(mesh),
    };
    write_file(path, &bytes)
}

fn read_obj(path: &Path) -> Result<TriMesh> {
    let opts = tobj::LoadOptions { triangulate: true, single_index: false, ignore_points: true, ignore_lines: true };
    let bytes = read_file(path)?;
    check_obj_indices(&bytes).map_err(|e| CoreError::format(path, format!("malformed OBJ: {e}")))?;
    // Parsed from memory with no material loader: an `mtllib` line is ignored rather than
    // followed (it may name any file, /dev/zero or a FIFO). tobj panics on some crafted index
    // lists (an overflow on a negative index past the list): caught and reported as a refusal.
    let parsed = std::panic::catch_unwind(|| {
        tobj::load_obj_buf(&mut std::io::Cursor::new(&bytes), &opts, |_| Ok(Default::default()))
    });
    let (models, _) = match parsed {
        Ok(result) => result.map_err(|e| CoreError::format(path, format!("malformed OBJ: {e}")))?,
        Err(_) => return Err(CoreError::format(path, "malformed OBJ: an index list the parser cannot read")),
    };
    let mut mesh = TriMesh::default();
    for m in models {
        let base = mesh.vertices.len() as u32;
        let p = &m.mesh.positions;
        mesh.vertices.extend(p.chunks_exact(3).map(|c| DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64)));
        mesh.faces.extend(m.mesh.indices.chunks_exact(3).map(|c| [c[0] + base, c[1] + base, c[2] + base]));
    }
    Ok(mesh)
}

/// Every index of every face element (`v`, `v/vt`, `v//vn`, `v/vt/vn`; 1-based, or negative
/// counting back from the last element read so far) refers to an element defined before it: the
/// parser does not check this everywhere (a negative index past the list overflows inside it).
fn check_obj_indices(bytes: &[u8]) -> Result<(), String> {
    let mut counts = [0i64; 3]; // v, vt, vn
    for (n, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => counts[0] += 1,
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("f") => {
                for element in words {
                    for (kind, index) in element.split('/').enumerate().take(3) {
                        if index.is_empty() {
                            continue;
                        }
                        let value: i64 = index
                            .parse()
                            .map_err(|_| format!("line {}: face index `{index}` is not a number", n + 1))?;
                        let count = counts[kind];
                        if value == 0 || value > count || value < -count {
                            let what = ["vertex", "texture coordinate", "normal"][kind];
                            return Err(format!(
                                "line {}: face index {value} refers to no {what} ({count} defined before it)",
                                n + 1
                            ));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

fn obj_bytes(mesh: &TriMesh) -> Vec<u8> {
    let mut s = String::with_capacity(mesh.vertices.len() * 32 + mesh.faces.len() * 24);
    s.push_str("# ctadsa mesh, world coordinates in mm\n");
    for v in &mesh.vertices {
        let _ = writeln!(s, "v {:.5} {:.5} {:.5}", v.x, v.y, v.z);
    }
    for f in &mesh.faces {
        let _ = writeln!(s, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    s.into_bytes()
}

fn ply_bytes(mesh: &TriMesh) -> Vec<u8> {
    ply_bytes_with(mesh, &[], "ctadsa mesh, world coordinates in mm")
}

/// Binary PLY of `mesh` with extra float vertex properties `columns` (name, one value per
/// vertex) after x, y, z.
fn ply_bytes_with(mesh: &TriMesh, columns: &[(&str, &[f64])], comment: &str) -> Vec<u8> {
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        mesh.vertices.len()
    );
    for (name, _) in columns {
        let _ = writeln!(header, "property float {name}");
    }
    let _ = write!(header, "element face {}\nproperty list uchar int vertex_indices\nend_header\n", mesh.faces.len());
    let mut out = header.into_bytes();
    for (k, v) in mesh.vertices.iter().enumerate() {
        let extra = columns.iter().map(|(_, values)| values.get(k).copied().unwrap_or(f64::NAN));
        for c in [v.x, v.y, v.z].into_iter().chain(extra) {
            out.extend((c as f32).to_le_bytes());
        }
    }
    for f in &mesh.faces {
        out.push(3);
        for &i in f {
            out.extend((i as i32).to_le_bytes());
        }
    }
    out
}

/// Writes `mesh` as binary PLY with extra float vertex properties `columns` (name, one value
/// per vertex), e.g. a per-vertex confidence.
pub fn write_ply_with(path: &Path, mesh: &TriMesh, columns: &[(&str, &[f64])], comment: &str) -> Result<()> {
    write_file(path, &ply_bytes_with(mesh, columns, comment))
}

/// Reads a PLY mesh (checked as [`read_mesh`] does) and the values of its scalar vertex
/// property `property` (an error naming the file when it has none).
pub fn read_ply_with(path: &Path, property: &str) -> Result<(TriMesh, Vec<f64>)> {
    let (mesh, values) = parse_ply_with(&read_file(path)?, Some(property)).map_err(|p| CoreError::format(path, p))?;
    validate(&mesh).map_err(|p| CoreError::format(path, p))?;
    if values.len() != mesh.vertices.len() {
        return Err(CoreError::format(path, format!("no vertex property `{property}`")));
    }
    Ok((mesh, values))
}

/// Writes a point cloud as binary PLY: one vertex element with float properties `columns`,
/// `rows[i]` holding the values of point `i` in column order.
pub fn write_point_ply(path: &Path, columns: &[&str], rows: &[Vec<f32>], comment: &str) -> Result<()> {
    let mut header =
        format!("ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {}\n", rows.len());
    for c in columns {
        let _ = writeln!(header, "property float {c}");
    }
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    for r in rows {
        if r.len() != columns.len() {
            return Err(CoreError::invalid(format!("point row has {} values for {} columns", r.len(), columns.len())));
        }
        for v in r {
            out.extend(v.to_le_bytes());
        }
    }
    write_file(path, &out)
}

/// A parsed PLY property.
#[derive(Debug, Clone)]
enum Prop {
    Scalar(String, String),
    List(String, String, String),
}

fn type_size(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "int8" | "uchar" | "uint8" => 1,
        "short" | "int16" | "ushort" | "uint16" => 2,
        "int" | "int32" | "uint" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

fn read_binary(bytes: &[u8], at: &mut usize, t: &str) -> std::result::Result<f64, String> {
    let n = type_size(t).ok_or_else(|| format!("unknown PLY type `{t}`"))?;
    let b = bytes.get(*at..*at + n).ok_or("PLY data ends early")?;
    *at += n;
    Ok(match t {
        "char" | "int8" => b[0] as i8 as f64,
        "uchar" | "uint8" => b[0] as f64,
        "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
        "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
        "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "uint" | "uint32" => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
    })
}

/// Longest list property a PLY row may hold (a face's vertices).
const MAX_PLY_LIST: usize = 1024;

/// One element of a PLY header: name, row count, properties.
type PlyElement = (String, usize, Vec<Prop>);

/// The header up to `end_header`: whether the body is ASCII, and the elements.
fn parse_ply_header(header: &str) -> std::result::Result<(bool, Vec<PlyElement>), String> {
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("not a PLY file (first line is not `ply`)".into());
    }
    let mut format = String::new();
    let mut elements: Vec<PlyElement> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = f.to_string(),
            ["element", name, count] => {
                let c = count.parse().map_err(|_| format!("bad element count `{count}`"))?;
                elements.push((name.to_string(), c, Vec::new()));
            }
            ["property", "list", ct, it, name] => elements
                .last_mut()
                .ok_or("property before element")?
                .2
                .push(Prop::List(ct.to_string(), it.to_string(), name.to_string())),
            ["property", t, name] => elements
                .last_mut()
                .ok_or("property before element")?
                .2
                .push(Prop::Scalar(t.to_string(), name.to_string())),
            _ => {}
        }
    }
    let ascii = match format.as_str() {
        "ascii" => true,
        "binary_little_endian" => false,
        other => return Err(format!("unsupported PLY format `{other}`")),
    };
    Ok((ascii, elements))
}

/// Every value takes at least one byte: a header claiming more rows than the data can hold is
/// refused before any row is read (and an element without properties holds no rows).
fn check_ply_sizes(elements: &[PlyElement], body_bytes: usize) -> std::result::Result<(), String> {
    let mut values = 0u128;
    for (name, count, props) in elements {
        if *count > 0 && props.is_empty() {
            return Err(format!("element `{name}` has {count} rows but no property"));
        }
        values += *count as u128 * props.len() as u128;
    }
    if values > body_bytes as u128 {
        return Err(format!("the header claims {values} values but the data holds {body_bytes} bytes"));
    }
    Ok(())
}

/// Parses a PLY mesh (ASCII or binary little-endian) with `vertex` x/y/z and `face`
/// `vertex_indices` (or `vertex_index`).
pub fn parse_ply(bytes: &[u8]) -> std::result::Result<TriMesh, String> {
    parse_ply_with(bytes, None).map(|(mesh, _)| mesh)
}

/// [`parse_ply`], also collecting the values of the scalar vertex property `property`.
fn parse_ply_with(bytes: &[u8], property: Option<&str>) -> std::result::Result<(TriMesh, Vec<f64>), String> {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").ok_or("not a PLY file (no `end_header`)")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "PLY header is not text")?;
    let (ascii, elements) = parse_ply_header(header)?;
    let body = &bytes[end + 11..];
    check_ply_sizes(&elements, body.len())?;
    let text = if ascii { std::str::from_utf8(body).map_err(|_| "PLY ASCII body is not text")? } else { "" };
    let mut tokens = text.split_whitespace();
    let mut at = 0usize;
    let mut next = |t: &str| -> std::result::Result<f64, String> {
        if ascii {
            tokens.next().ok_or("PLY data ends early")?.parse::<f64>().map_err(|e| format!("bad PLY number: {e}"))
        } else {
            read_binary(body, &mut at, t)
        }
    };
    let mut mesh = TriMesh::default();
    let mut values = Vec::new();
    for (name, count, props) in &elements {
        for _ in 0..*count {
            let mut xyz = [f64::NAN; 3];
            for p in props {
                match p {
                    Prop::Scalar(t, pn) => {
                        let v = next(t)?;
                        if name == "vertex" {
                            match pn.as_str() {
                                "x" => xyz[0] = v,
                                "y" => xyz[1] = v,
                                "z" => xyz[2] = v,
                                other if Some(other) == property => values.push(v),
                                _ => {}
                            }
                        }
                    }
                    Prop::List(ct, it, pn) => {
                        let count = next(ct)?;
                        if !(0.0..=MAX_PLY_LIST as f64).contains(&count) {
                            return Err(format!("a `{pn}` list of {count} entries (at most {MAX_PLY_LIST})"));
                        }
                        let idx =
                            (0..count as usize).map(|_| next(it)).collect::<std::result::Result<Vec<f64>, _>>()?;
                        if name == "face" && (pn == "vertex_indices" || pn == "vertex_index") {
                            if idx.iter().any(|&i| i < 0.0) {
                                return Err(format!("negative vertex index in face {}", mesh.faces.len()));
                            }
                            for k in 1..idx.len().saturating_sub(1) {
                                mesh.faces.push([idx[0] as u32, idx[k] as u32, idx[k + 1] as u32]);
                            }
                        }
                    }
                }
            }
            if name == "vertex" {
                mesh.vertices.push(DVec3::from(xyz));
            }
        }
    }
    Ok((mesh, values))
}

fn stl_bytes(mesh: &TriMesh) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..32].copy_from_slice(b"ctadsa mesh, world coordinates  ");
    out.extend((mesh.faces.len() as u32).to_le_bytes());
    for f in &mesh.faces {
        let [a, b, c] = f.map(|i| mesh.vertices[i as usize]);
        let n = (b - a).cross(c - a).normalize_or_zero();
        for v in [n, a, b, c] {
            for x in [v.x, v.y, v.z] {
                out.extend((x as f32).to_le_bytes());
            }
        }
        out.extend([0u8, 0u8]);
    }
    out
}

/// Parses binary or ASCII STL; vertices are welded by exact position.
pub fn parse_stl(bytes: &[u8]) -> std::result::Result<TriMesh, String> {
    let mut tris: Vec<[DVec3; 3]> = Vec::new();
    let binary_len =
        (bytes.len() >= 84).then(|| u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize);
    if let Some(n) = binary_len.filter(|&n| 84 + 50 * n == bytes.len()) {
        for t in 0..n {
            let base = 84 + 50 * t + 12;
            let f = |k: usize| {
                let o = base + 4 * k;
                f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]) as f64
            };
            tris.push([0, 1, 2].map(|v| DVec3::new(f(3 * v), f(3 * v + 1), f(3 * v + 2))));
        }
    } else {
        let text = std::str::from_utf8(bytes).map_err(|_| "neither binary STL (size mismatch) nor ASCII STL")?;
        if !text.trim_start().starts_with("solid") {
            return Err("neither binary STL (size mismatch) nor ASCII STL (no `solid`)".into());
        }
        let mut current = Vec::new();
        for (ln, line) in text.lines().enumerate() {
            let w: Vec<&str> = line.split_whitespace().collect();
            if w.first() == Some(&"vertex") {
                if w.len() != 4 {
                    return Err(format!("line {}: `vertex` needs 3 numbers", ln + 1));
                }
                let p: std::result::Result<Vec<f64>, _> = w[1..].iter().map(|s| s.parse::<f64>()).collect();
                let p = p.map_err(|e| format!("line {}: {e}", ln + 1))?;
                current.push(DVec3::new(p[0], p[1], p[2]));
            } else if w.first() == Some(&"endfacet") {
                if current.len() != 3 {
                    return Err(format!("line {}: facet with {} vertices", ln + 1, current.len()));
                }
                tris.push([current[0], current[1], current[2]]);
                current.clear();
            }
        }
    }
    let mut mesh = TriMesh::default();
    let mut index: std::collections::HashMap<[u64; 3], u32> = std::collections::HashMap::new();
    for t in tris {
        let f = t.map(|p| {
            *index.entry([p.x.to_bits(), p.y.to_bits(), p.z.to_bits()]).or_insert_with(|| {
                mesh.vertices.push(p);
                mesh.vertices.len() as u32 - 1
            })
        });
        mesh.faces.push(f);
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> TriMesh {
        TriMesh {
            vertices: vec![
                DVec3::new(0.0, 0.0, 0.0),
                DVec3::new(1.0, 0.0, 0.0),
                DVec3::new(0.0, 1.0, 0.0),
                DVec3::new(0.0, 0.0, 1.5),
            ],
            faces: vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]],
        }
    }

    #[test]
    fn round_trips_in_every_format() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        for ext in ["obj", "ply", "stl"] {
            let path = dir.join(format!("t.{ext}"));
            write_mesh(&path, &tetra()).unwrap();
            let back = read_mesh(&path).unwrap();
            assert_eq!(back.faces.len(), 4, "{ext}");
            assert_eq!(back.open_edges(), 0, "{ext}");
            assert!((back.signed_volume_mm3() - tetra().signed_volume_mm3()).abs() < 1e-6, "{ext}");
        }
    }

    #[test]
    fn ascii_ply_and_errors() {
        let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let m = parse_ply(ply).unwrap();
        assert_eq!(m.faces, vec![[0, 1, 2]]);
        assert!(parse_ply(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n").is_err());
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let bad = dir.join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
        let err = read_mesh(&bad).unwrap_err().to_string();
        assert!(err.contains("bad.obj"), "{err}");
        let missing = read_mesh(&dir.join("none.stl")).unwrap_err().to_string();
        assert!(missing.contains("none.stl"), "{missing}");
    }
}
