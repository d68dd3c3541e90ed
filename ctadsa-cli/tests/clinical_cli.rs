//! The clinical commands end to end through the binary: synth → export-dicom (files that
//! dciodvfy accepts and dcmdump reads) → import-dsa gives a loadable case with the same views; `prior` makes a mesh from the TopCoW labels; bad paths fail
//! with a message that names the file.

use std::path::Path;
use std::process::{Command, Output};

use ctadsa_core::data::case::Case;

mod common;
use common::{BIN, tmp};

fn ctadsa(args: &[&str]) -> Output {
    Command::new(BIN).args(args).output().expect("ctadsa runs")
}

fn ok(args: &[&str]) -> String {
    let out = ctadsa(args);
    assert!(out.status.success(), "ctadsa {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `dciodvfy` (dicom3tools) reports no error and `dcmdump` (dcmtk) reads the file. Without the
/// tools the check prints why and passes, unless `CTADSA_REQUIRE_DICOM_TOOLS=1` (CI).
fn validate_dicom(file: &Path) {
    let required = std::env::var("CTADSA_REQUIRE_DICOM_TOOLS").is_ok_and(|v| v == "1");
    for tool in ["dciodvfy", "dcmdump"] {
        let Ok(out) = Command::new(tool).arg(file).output() else {
            assert!(!required, "CTADSA_REQUIRE_DICOM_TOOLS=1 but `{tool}` is not on the PATH");
            eprintln!("SKIPPED: `{tool}` check of {} not run: `{tool}` is not on the PATH", file.display());
            continue;
        };
        let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
        if tool == "dciodvfy" {
            let errors: Vec<&str> = text.lines().filter(|l| l.starts_with("Error")).collect();
            assert!(
                errors.is_empty(),
                "dciodvfy {}: {} error(s):\n{}",
                file.display(),
                errors.len(),
                errors.join("\n")
            );
        } else {
            assert!(
                out.status.success() && text.contains("PositionerPrimaryAngle"),
                "dcmdump {}:\n{text}",
                file.display()
            );
        }
    }
}

#[test]
fn dicom_round_trip_through_the_commands() {
    let (src, dicom, case) = (tmp("src"), tmp("dicom"), tmp("case"));
    ok(&["synth", "--out", s(&src), "--terminals", "16", "--detector-px", "96", "--binning", "2", "--voxel-mm", "0.6"]);
    ok(&["export-dicom", "--case", s(&src), "--out", s(&dicom), "--mirror-first"]);
    for view in ["ap", "lat", "oblique"] {
        validate_dicom(&dicom.join(format!("{view}.dcm")));
    }
    let prior = src.join("priors/d1p50mm/prior.obj");
    let log = ok(&[
        "import-dsa",
        "--run",
        s(&dicom.join("ap.dcm")),
        "--run",
        s(&dicom.join("lat.dcm")),
        "--prior",
        s(&prior),
        "--out",
        s(&case),
    ]);
    assert!(log.contains("MIP 3–5"), "frames chosen from the bolus: {log}");
    let (a, b) = (Case::load(&case).unwrap(), Case::load(&src).unwrap());
    assert_eq!(a.views.len(), 2);
    for k in 0..2 {
        let p = glam::DVec3::new(3.0, -2.0, 1.0);
        let (pa, pb) = (a.views.views()[k].project(p).unwrap(), b.views.views()[k].project(p).unwrap());
        assert!((pa - pb).length() < 1e-9, "view {k}: {pa:?} vs {pb:?}");
        // Same image up to scale: compare normalised by each image's maximum.
        let (ia, ib) = (&a.images[k], &b.images[k]);
        let worst =
            ia.data.iter().zip(&ib.data).map(|(x, y)| (x / ia.max() - y / ib.max()).abs()).fold(0.0f32, f32::max);
        assert!(worst < 2e-3, "view {k}: images differ by {worst}");
    }

    // A missing run file and a non-DICOM file: errors that name them.
    let out = ctadsa(&["import-dsa", "--run", "/nonexistent/run.dcm", "--out", s(&tmp("none"))]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/run.dcm"));
    let out = ctadsa(&["import-dsa", "--run", s(&prior), "--out", s(&tmp("none"))]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("prior.obj") && err.contains("DICOM"), "{err}");
}

#[test]
fn prior_and_report_commands() {
    let labels = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data/topcow/topcow_ct_roi_003.nii.gz");
    let mesh = tmp("topcow").join("prior.obj");
    let log = ok(&["prior", "--labels", labels, "--centre-prior", "--label-ids", "1,2,3", "--out", s(&mesh)]);
    assert!(log.contains("triangles"), "{log}");
    assert!(std::fs::metadata(&mesh).unwrap().len() > 1000);
    let out = ctadsa(&["prior", "--labels", labels, "--label-ids", "99", "--out", s(&mesh)]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("labels present"));
    let out = ctadsa(&["report", s(&tmp("no-run"))]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("summary.json"));
}
