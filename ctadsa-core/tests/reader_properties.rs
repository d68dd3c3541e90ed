//! Property tests of the readers of user files: arbitrary or mutated input is either parsed into
//! something the method can use, or refused with an error — never a panic or a huge allocation.

use std::path::Path;

use ctadsa_core::config::Config;
use ctadsa_core::data::case::CaseFile;
use ctadsa_core::data::mesh::io::{parse_ply, parse_stl};
use ctadsa_core::data::tree::swc::{MAX_COORDINATE_MM, MAX_RADIUS_MM, parse_swc};
use proptest::prelude::*;

/// Numbers as they appear in real and broken files.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        (-200.0f64..200.0).prop_map(|v| format!("{v}")),
        (-5i64..40).prop_map(|v| v.to_string()),
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-1e300".to_string()),
        Just("1e30".to_string()),
        Just("0".to_string()),
        "[a-z#]{0,3}",
    ]
}

/// An SWC-like line: 5–8 columns of numbers, or a comment, or noise.
fn swc_line() -> impl Strategy<Value = String> {
    prop_oneof![
        8 => prop::collection::vec(number(), 5..=8).prop_map(|c| c.join(" ")),
        1 => "# [ -~]{0,20}",
        1 => "[ -~]{0,30}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    #[test]
    fn swc_text_parses_to_a_usable_tree_or_is_refused(lines in prop::collection::vec(swc_line(), 0..40)) {
        let text = lines.join("\n");
        if let Ok(file) = parse_swc(&text) {
            let n = file.tree.nodes.len();
            prop_assert!(n >= 1);
            for node in &file.tree.nodes {
                prop_assert!(node.position_mm.is_finite());
                prop_assert!(node.position_mm.abs().max_element() <= MAX_COORDINATE_MM);
                prop_assert!(node.radius_mm > 0.0 && node.radius_mm <= MAX_RADIUS_MM);
                prop_assert!(node.parent.is_none_or(|p| p < n));
            }
            // No parent cycle: every walk to a root ends within n steps.
            for start in 0..n {
                let (mut cur, mut steps) = (Some(start), 0);
                while let Some(c) = cur {
                    cur = file.tree.nodes[c].parent;
                    steps += 1;
                    prop_assert!(steps <= n, "parent cycle through node {start}");
                }
            }
        }
    }

    #[test]
    fn ply_bytes_never_panic(header in prop::collection::vec("(element (vertex|face) [0-9]{1,12}|property (float|uchar|int) [xyz]|property list (uchar|float) int vertex_indices|format (ascii|binary_little_endian) 1.0)", 0..8),
                             body in prop::collection::vec(any::<u8>(), 0..200)) {
        let mut bytes = format!("ply\n{}\nend_header\n", header.join("\n")).into_bytes();
        bytes.extend(body);
        let _ = parse_ply(&bytes);
    }

    #[test]
    fn stl_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..400), count in any::<u32>()) {
        let mut b = bytes.clone();
        if b.len() >= 84 {
            b[80..84].copy_from_slice(&count.to_le_bytes());
        }
        let _ = parse_stl(&b);
        let _ = parse_stl(&bytes);
    }

    #[test]
    fn mutated_case_files_never_panic(at in 0usize..2000, byte in any::<u8>(), cut in 0usize..2000) {
        let text = valid_case_json();
        let mut bytes = text.as_bytes().to_vec();
        let i = at % bytes.len();
        bytes[i] = byte;
        bytes.truncate(bytes.len() - cut % bytes.len());
        let _ = CaseFile::parse(&String::from_utf8_lossy(&bytes), Path::new("case.json"));
    }

    #[test]
    fn config_overrides_are_validated_or_refused(key in "(run|init|field|optim|loss|densify|output)\\.[a-z_0-9]{1,16}",
                                                 value in number()) {
        let _ = Config::load(None, &[format!("{key}={value}")]);
    }
}

/// A valid `case.json` text (two views), as `synth` writes it.
fn valid_case_json() -> String {
    let view = |name: &str, primary: f64| {
        serde_json::json!({
            "name": name, "image": format!("views/{name}.tiff"),
            "geometry": {"kind": "tigre", "dsd_mm": 700.0, "dso_mm": 500.0, "detector_px": [48, 48],
                         "pixel_mm": [1.0, 1.0], "offset_mm": [0.0, 0.0], "primary_deg": primary, "secondary_deg": 0.0}
        })
    };
    let case = serde_json::json!({
        "format": "ctadsa-case", "version": 1, "name": "fuzz",
        "provenance": {"source": "test", "generator": "test", "notes": []},
        "image_values": {"units": "mm", "normalised_by": null, "contrast_per_mm": 1.0},
        "volume": {"min_mm": [-20.0, -20.0, -20.0], "max_mm": [20.0, 20.0, 20.0], "voxel_mm": 0.5},
        "views": [view("ap", -90.0), view("lat", 0.0)]
    });
    let text = serde_json::to_string_pretty(&case).unwrap();
    CaseFile::parse(&text, Path::new("case.json")).expect("the seed case is valid");
    text
}
