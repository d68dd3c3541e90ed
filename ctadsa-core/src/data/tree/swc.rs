//! SWC centreline files: one node per line, `id type x y z radius parent` (mm), parent −1 for a
//! root, `#` comments. Malformed rows are skipped and reported with their line numbers.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use glam::DVec3;

use super::{TreeNode, VesselTree};
use crate::error::{CoreError, Result, read_file, write_file};

/// A row that was skipped while reading, with the reason.
#[derive(Debug, Clone, PartialEq)]
pub struct SwcWarning {
    /// 1-based line number.
    pub line: usize,
    pub problem: String,
}

/// A parsed SWC file: the tree and the rows that could not be used.
#[derive(Debug, Clone)]
pub struct SwcFile {
    pub tree: VesselTree,
    pub warnings: Vec<SwcWarning>,
}

/// Largest radius a node may have (mm): no cerebral vessel comes close.
pub const MAX_RADIUS_MM: f64 = 100.0;
/// Largest coordinate a node may have (mm): a head fits in ±300 mm of any sensible origin.
pub const MAX_COORDINATE_MM: f64 = 100_000.0;

/// Reads an SWC file. Fails (naming the file) if it cannot be read or holds no usable node;
/// malformed rows (wrong column count, unparsable numbers, radius outside (0, 100] mm,
/// coordinates beyond ±10⁵ mm, duplicate ids, unknown parents) are skipped and listed in [`SwcFile::warnings`].
pub fn read_swc(path: &Path) -> Result<SwcFile> {
    let bytes = read_file(path)?;
    let text = String::from_utf8_lossy(&bytes);
    parse_swc(&text).map_err(|problem| CoreError::format(path, problem))
}

/// One parsed SWC row.
struct Row {
    id: i64,
    kind: i32,
    pos: DVec3,
    radius: f64,
    parent: i64,
    line: usize,
}

/// The seven columns of a row, range-checked.
fn parse_row(cols: &[&str], line: usize) -> std::result::Result<Row, String> {
    let int = |s: &str, what: &str| {
        s.parse::<f64>()
            .ok()
            .filter(|v| v.fract() == 0.0 && v.is_finite())
            .map(|v| v as i64)
            .ok_or_else(|| format!("{what} `{s}` is not an integer"))
    };
    let num = |s: &str, what: &str| {
        s.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| format!("{what} `{s}` is not a finite number"))
    };
    let radius = num(cols[5], "radius")?;
    if radius <= 0.0 || radius > MAX_RADIUS_MM {
        return Err(format!("radius {radius} mm is not in (0, {MAX_RADIUS_MM}] mm"));
    }
    for (c, axis) in cols[2..5].iter().zip(["x", "y", "z"]) {
        let v = num(c, axis)?;
        if v.abs() > MAX_COORDINATE_MM {
            return Err(format!("{axis} = {v:.3e} mm is farther than {MAX_COORDINATE_MM} mm from the origin"));
        }
    }
    Ok(Row {
        id: int(cols[0], "id")?,
        kind: int(cols[1], "type")? as i32,
        pos: DVec3::new(num(cols[2], "x")?, num(cols[3], "y")?, num(cols[4], "z")?),
        radius,
        parent: int(cols[6], "parent")?,
        line,
    })
}

/// The usable rows (first of each id) and the index of each id among them.
fn parse_rows(text: &str, warnings: &mut Vec<SwcWarning>) -> (Vec<Row>, HashMap<i64, usize>) {
    let mut rows: Vec<Row> = Vec::new();
    let mut seen: HashMap<i64, usize> = HashMap::new();
    for (k, raw) in text.lines().enumerate() {
        let line = k + 1;
        let body = raw.split('#').next().unwrap_or("").trim();
        if body.is_empty() {
            continue;
        }
        let cols: Vec<&str> = body.split_whitespace().collect();
        if cols.len() != 7 {
            warnings.push(SwcWarning {
                line,
                problem: format!("expected 7 columns (id type x y z radius parent), found {}", cols.len()),
            });
            continue;
        }
        match parse_row(&cols, line) {
            Ok(row) => {
                if let Some(&first) = seen.get(&row.id) {
                    warnings.push(SwcWarning {
                        line,
                        problem: format!("duplicate id {} (first on line {})", row.id, rows[first].line),
                    });
                    continue;
                }
                seen.insert(row.id, rows.len());
                rows.push(row);
            }
            Err(problem) => warnings.push(SwcWarning { line, problem }),
        }
    }
    (rows, seen)
}

/// Makes a root of every node that closes a parent cycle (a malformed file can have them),
/// walking up from every node.
fn break_cycles(nodes: &mut [TreeNode], rows: &[Row], warnings: &mut Vec<SwcWarning>) {
    let n = nodes.len();
    let mut state = vec![0u8; n]; // 0 unvisited, 1 on stack, 2 done
    for start in 0..n {
        let mut path = Vec::new();
        let mut cur = Some(start);
        while let Some(c) = cur {
            if state[c] == 2 {
                break;
            }
            if state[c] == 1 {
                warnings.push(SwcWarning {
                    line: rows[c].line,
                    problem: format!("node {} closes a parent cycle; made a root", rows[c].id),
                });
                nodes[c].parent = None;
                break;
            }
            state[c] = 1;
            path.push(c);
            cur = nodes[c].parent;
        }
        for p in path {
            state[p] = 2;
        }
    }
}

/// Parses SWC text (see [`read_swc`]); the error string describes why nothing was usable.
pub fn parse_swc(text: &str) -> std::result::Result<SwcFile, String> {
    let mut warnings = Vec::new();
    let (rows, seen) = parse_rows(text, &mut warnings);
    if rows.is_empty() {
        return Err(match warnings.first() {
            Some(w) => format!(
                "no usable SWC node: {} row(s) refused, the first at line {}: {} (coordinates and radii are in mm)",
                warnings.len(),
                w.line,
                w.problem
            ),
            None => "no usable SWC node".into(),
        });
    }
    let mut nodes = Vec::with_capacity(rows.len());
    for row in &rows {
        let parent = if row.parent < 0 {
            None
        } else if let Some(&p) = seen.get(&row.parent) {
            if p == nodes.len() {
                warnings.push(SwcWarning {
                    line: row.line,
                    problem: format!("node {} is its own parent; made a root", row.id),
                });
                None
            } else {
                Some(p)
            }
        } else {
            warnings.push(SwcWarning {
                line: row.line,
                problem: format!("parent {} of node {} does not exist; made a root", row.parent, row.id),
            });
            None
        };
        nodes.push(TreeNode { id: row.id, kind: row.kind, position_mm: row.pos, radius_mm: row.radius, parent });
    }
    break_cycles(&mut nodes, &rows, &mut warnings);
    Ok(SwcFile { tree: VesselTree { nodes }, warnings })
}

/// Writes a tree as SWC (ids renumbered from 1 in node order).
pub fn write_swc(path: &Path, tree: &VesselTree, header: &str) -> Result<()> {
    let mut out = String::new();
    for line in header.lines() {
        let _ = writeln!(out, "# {line}");
    }
    for (i, n) in tree.nodes.iter().enumerate() {
        let parent = n.parent.map_or(-1, |p| p as i64 + 1);
        let p = n.position_mm;
        let _ = writeln!(out, "{} {} {:.4} {:.4} {:.4} {:.4} {}", i + 1, n.kind, p.x, p.y, p.z, n.radius_mm, parent);
    }
    write_file(path, out.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_reports_malformed_rows() {
        let text = "# header\n1 1 0 0 0 2.0 -1\n2 1 1 0 0 1.5 1\n3 1 2 0 0 1.0\n4 1 x 0 0 1 2\n\
                    5 1 3 0 0 -1 2\n2 1 9 9 9 1 1\n6 1 4 0 0 0.5 99\n7 1 5 0 0 0.5 2 # ok\n";
        let f = parse_swc(text).unwrap();
        assert_eq!(f.tree.nodes.len(), 4, "{:?}", f.tree.nodes);
        let lines: Vec<usize> = f.warnings.iter().map(|w| w.line).collect();
        assert_eq!(lines, vec![4, 5, 6, 7, 8], "{:?}", f.warnings);
        assert!(f.warnings[0].problem.contains("7 columns"));
        assert!(f.warnings[1].problem.contains("`x`"));
        assert!(f.warnings[2].problem.contains("is not in (0, 100] mm"));
        assert!(f.warnings[3].problem.contains("duplicate id 2"));
        assert!(f.warnings[4].problem.contains("parent 99"));
        assert_eq!(f.tree.nodes[1].parent, Some(0));
        assert_eq!(f.tree.nodes[2].parent, None); // node 6, unknown parent → root
        assert_eq!(f.tree.segments().len(), 2);
    }

    #[test]
    fn cycles_are_broken() {
        let f = parse_swc("1 1 0 0 0 1 2\n2 1 1 0 0 1 1\n").unwrap();
        assert!(f.tree.nodes.iter().any(|n| n.parent.is_none()));
        assert_eq!(f.warnings.len(), 1);
    }

    #[test]
    fn empty_file_is_an_error() {
        assert!(parse_swc("# nothing\n\n").is_err());
    }

    /// A tree in micrometres refuses every row by its radius: the error says which and why.
    #[test]
    fn a_tree_with_no_usable_row_says_why() {
        let e = parse_swc("1 1 95170 -102300 100440 930 -1\n2 3 93930 -99820 99820 930 1\n").unwrap_err();
        assert!(e.contains("2 row(s) refused") && e.contains("line 1") && e.contains("radius 930"), "{e}");
    }
}
