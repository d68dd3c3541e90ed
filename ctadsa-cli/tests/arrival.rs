//! Time-resolved cases through the binary: `synth --arrival-fps` writes arrival maps the case
//! reads back, a 2-view run checks each new branch against them (and a 3-view run does not), and
//! malformed maps are refused naming the file.

use std::path::Path;
use std::process::{Command, Output};

mod common;
use common::{BIN, tmp};

fn ctadsa(dir: &Path, args: &[&str]) -> Output {
    Command::new(BIN).current_dir(dir).args(args).env("RUST_BACKTRACE", "0").output().unwrap()
}

fn ok(dir: &Path, args: &[&str]) -> String {
    let out = ctadsa(dir, args);
    assert!(out.status.success(), "`ctadsa {}`: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `complete` on `case` with the quick config shrunk to a few steps, into `out`, with `views`.
fn complete(dir: &Path, case: &str, out: &str, views: &str) -> serde_json::Value {
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
    let mut args = vec!["complete", "--case", case, "--config", config, "--out", out];
    let views = format!("run.views={views}");
    for s in [
        "run.iterations=6",
        "init.n1=600",
        "init.n2=300",
        "densify.enabled=false",
        "output.metric_samples=2000",
        "run.prior_only_member=false",
        &views,
    ] {
        args.extend(["--set", s]);
    }
    ok(dir, &args);
    serde_json::from_slice(&std::fs::read(dir.join(out).join("summary.json")).unwrap()).unwrap()
}

#[test]
fn arrival_maps_are_written_read_and_check_new_branches_in_two_views() {
    let dir = tmp("arrival");
    std::fs::create_dir_all(&dir).unwrap();
    let synth = ["synth", "--out", "case", "--terminals", "16", "--detector-px", "96", "--binning", "2"];
    // The planes imaged alternately: the second view's frames half a frame late, which the case
    // says (`arrival_offset_frames`), and the DICOM runs carry through their Acquisition Times.
    ok(&dir, &[&synth[..], &["--voxel-mm", "0.6", "--arrival-fps", "7.5", "--arrival-interleave", "0.5"]].concat());
    let offsets = |case: &str| -> Vec<f64> {
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(case).join("case.json")).unwrap()).unwrap();
        let views = json["views"].as_array().unwrap();
        for view in views {
            let name = view["name"].as_str().unwrap();
            assert_eq!(view["arrival"], format!("views/{name}-arrival.tiff"));
            assert!(dir.join(case).join(view["arrival"].as_str().unwrap()).is_file());
        }
        views.iter().map(|v| v["arrival_offset_frames"].as_f64().unwrap_or(0.0)).collect()
    };
    assert_eq!(offsets("case"), vec![0.0, 0.5, 0.0]);
    // Two views: every new branch is checked (a share in branches.csv) and the summary counts
    // the branches dropped; three views: none is.
    for (views, checked) in [("[0,1]", true), ("[0,1,2]", false)] {
        let out = format!("run-{}", views.len());
        let summary = complete(&dir, "case", &out, views);
        let dropped = &summary["centreline"]["arrival_dropped_branches"];
        assert_eq!(dropped.is_u64(), checked, "{views}: {dropped}");
        let csv = std::fs::read_to_string(dir.join(&out).join("branches.csv")).unwrap();
        assert!(csv.lines().next().unwrap().ends_with(",arrival_agreement"));
        for row in csv.lines().skip(1) {
            let cells: Vec<&str> = row.split(',').collect();
            let (new, agreement) = (cells[1] == "1", *cells.last().unwrap());
            if new && checked {
                let share: f64 = agreement.parse().unwrap();
                assert!((0.0..=1.0).contains(&share), "{row}");
            } else {
                assert!(agreement.is_empty(), "{views}: {row}");
            }
        }
    }
    // The image seeds of a 2-view run: with `init.arrival_seeds` those whose two views fill at
    // different times are dropped, so fewer of them lie off every true vessel.
    let ghosts = |checked: bool| {
        let json = format!("seeds-{checked}.json");
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let arrival = format!("init.arrival_seeds={checked}");
        let sets = ["run.views=[0,1]", "run.prior_only_member=false", "init.n2=300", &arrival];
        let mut args = vec!["diagnose", "--seeds", "--case", "case", "--config", config, "--json", &json];
        for s in sets.iter() {
            args.extend(["--set", s]);
        }
        ok(&dir, &args);
        let d: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join(&json)).unwrap()).unwrap();
        d["ghosts"].as_f64().unwrap()
    };
    let (unchecked, checked) = (ghosts(false), ghosts(true));
    assert!(checked < unchecked, "ghost seeds {unchecked} -> {checked}");
    // The re-seeds of training (`densify.reseed_at`, every candidate taken): with
    // `init.arrival_reseeds` those whose two views fill at different times are dropped.
    let seeds = |checked: bool| {
        let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
        let (out, arrival) = (format!("reseed-{checked}"), format!("init.arrival_reseeds={checked}"));
        let mut args = vec!["complete", "--case", "case", "--config", config, "--out", &out];
        for s in [
            "run.views=[0,1]",
            "run.iterations=4",
            "run.prior_only_member=false",
            "init.n1=600",
            "init.n2=300",
            "densify.reseed_at=[2]",
            "densify.reseed_n=100000",
            "densify.max_gaussians=1000000",
            "output.metric_samples=2000",
            &arrival,
        ] {
            args.extend(["--set", s]);
        }
        ok(&dir, &args);
        let summary: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join(&out).join("summary.json")).unwrap()).unwrap();
        summary["n2"].as_u64().unwrap()
    };
    let (unchecked, checked) = (seeds(false), seeds(true));
    assert!(checked < unchecked && unchecked > 300, "image seeds and re-seeds {unchecked} -> {checked}");
    // Through DICOM: export-dicom writes time-resolved runs (the contrast of each pixel turns on
    // after its arrival), import-dsa --arrival derives the maps back: the same frames wherever
    // the view shows a vessel, the frontal run mirrored and flipped back on the way.
    ok(&dir, &["export-dicom", "--case", "case", "--out", "dicom", "--mirror-first"]);
    let prior = "case/priors/d1p50mm/prior.obj";
    ok(
        &dir,
        &[
            "import-dsa",
            "--run",
            "dicom/ap.dcm",
            "--run",
            "dicom/lat.dcm",
            "--prior",
            prior,
            "--arrival",
            "--out",
            "imported",
        ],
    );
    let imported = offsets("imported");
    assert!(imported[0] == 0.0 && (imported[1] - 0.5).abs() < 1e-6, "imported arrival offsets {imported:?}");
    for (source, imported) in [("ap", "0-ap"), ("lat", "1-lat")] {
        let read = |p: &str| ctadsa_core::data::case::images::read_image(&dir.join(p), None).unwrap();
        let (a, b) = (
            read(&format!("case/views/{source}-arrival.tiff")),
            read(&format!("imported/views/{imported}-arrival.tiff")),
        );
        let image = read(&format!("case/views/{source}.tiff"));
        let vessel: Vec<usize> =
            (0..image.data.len()).filter(|&i| a.data[i] >= 0.0 && image.data[i] > 0.1 * image.max()).collect();
        assert!(vessel.len() > 50, "{source}: {} vessel pixels", vessel.len());
        let same = vessel.iter().filter(|&&i| a.data[i] == b.data[i]).count();
        assert_eq!(same, vessel.len(), "{source}: {same} of {} vessel pixels keep their frame", vessel.len());
    }
    // Malformed maps: another size, a fractional frame; and --arrival-fps with a label volume.
    let map = dir.join("case/views/ap-arrival.tiff");
    let good = std::fs::read(&map).unwrap();
    std::fs::copy(dir.join("case/views/ap.tiff"), &map).unwrap();
    let out = ctadsa(&dir, &["complete", "--case", "case", "--out", "run-bad", "--set", "run.iterations=1"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("ap-arrival.tiff") && stderr.contains("whole frames"), "{stderr}");
    // A frame past any run, and a map where nothing fills (it would reject every point).
    std::fs::write(&map, &good).unwrap();
    let image = ctadsa_core::data::case::images::read_image(&map, None).unwrap();
    for (name, value, expect) in [("huge", 1e30f32, "100000"), ("empty", -1.0, "no pixel")] {
        let data = image.data.iter().map(|&f| if f >= 0.0 || value < 0.0 { value } else { f }).collect();
        let edited = ctadsa_core::data::case::images::Image { data, ..image.clone() };
        ctadsa_core::data::case::images::write_tiff_f32(&map, &edited).unwrap();
        let out =
            ctadsa(&dir, &["complete", "--case", "case", "--out", &format!("run-{name}"), "--set", "run.iterations=1"]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains("ap-arrival.tiff") && stderr.contains(expect),
            "{name}: {stderr}"
        );
    }
    std::fs::write(&map, good).unwrap();
    let labels = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data/topcow/topcow_ct_roi_003.nii.gz");
    let out = ctadsa(&dir, &["synth", "--labels", labels, "--out", "labels", "--arrival-fps", "5"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("arrival maps") && stderr.contains("tree"), "{stderr}");
    // Contrast so slow that its frames pass what a case may hold: refused, naming both settings;
    // so fast that every vessel fills in one frame: written, with a warning.
    let slow = ["--voxel-mm", "0.6", "--arrival-fps", "7.5", "--flow-mm-s", "1e-6"];
    let out = ctadsa(&dir, &[&synth[..2], &["slow"], &synth[3..], &slow].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("--arrival-fps") && stderr.contains("--flow-mm-s"), "{stderr}");
    let fast = ["--voxel-mm", "0.6", "--arrival-fps", "0.1", "--flow-mm-s", "1e5"];
    let stdout = ok(&dir, &[&synth[..2], &["fast"], &synth[3..], &fast].concat());
    assert!(stdout.contains("warning: every vessel fills in frame 0"), "{stdout}");
}
