//! A corpus of malformed inputs, one per kind of input every command reads (SWC, NIfTI, OBJ,
//! case.json, TOML and `--set`, DICOM XA, CLI flags, checkpoints), made in the test. Each must be
//! refused with a non-zero exit, no panic or abort, a message naming the file or key, and no
//! file written outside the command's output folder.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

#[path = "../../tests/scratch/mod.rs"]
mod scratch;
use scratch::scratch;

const BIN: &str = env!("CARGO_BIN_EXE_ctadsa");

fn quick_config() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml").to_string()
}

/// A fresh folder for one test.
fn sandbox(name: &str) -> PathBuf {
    let dir = scratch(&format!("malformed-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small valid case, synthesised once per test process.
fn valid_case() -> &'static Path {
    static CASE: OnceLock<PathBuf> = OnceLock::new();
    CASE.get_or_init(|| {
        let dir = sandbox("valid").join("case");
        let out = Command::new(BIN)
            .args(["synth", "--out", dir.to_str().unwrap(), "--terminals", "16", "--detector-px", "96"])
            .args(["--binning", "2", "--voxel-mm", "0.6"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        dir
    })
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

/// Every file path under `dir`.
fn files_under(dir: &Path) -> BTreeSet<PathBuf> {
    let mut out = BTreeSet::new();
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(files_under(&p));
            }
            out.insert(p);
        }
    }
    out
}

/// Runs `args` in `dir` and checks a clean refusal whose message contains every `expect`;
/// files may appear only under `dir/out`.
fn refused(dir: &Path, args: &[&str], expect: &[&str]) {
    let before = files_under(dir);
    let out = Command::new(BIN).current_dir(dir).args(args).env("RUST_BACKTRACE", "0").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let what = format!("`ctadsa {}`", args.join(" "));
    assert!(out.status.code().is_some(), "{what} was killed by a signal (abort?): {stderr}");
    assert_ne!(out.status.code(), Some(0), "{what} accepted a malformed input: {stderr}");
    assert!(!stderr.contains("panicked"), "{what} panicked: {stderr}");
    for e in expect {
        assert!(stderr.contains(e), "{what}: the message does not name `{e}`:\n{stderr}");
    }
    let allowed = dir.join("out");
    for f in files_under(dir).difference(&before) {
        assert!(f.starts_with(&allowed), "{what} wrote {} outside its output folder", f.display());
    }
}

#[test]
fn malformed_swc_trees_are_refused_naming_the_file() {
    let dir = sandbox("swc");
    let corpus: &[(&str, &str)] = &[
        ("huge-coordinate", "1 1 1e300 0 0 1 -1\n2 1 0 0 0 1 1\n"),
        ("huge-radius", "1 1 0 0 0 1e30 -1\n2 1 1 0 0 1e30 1\n"),
        ("nan", "1 1 nan 0 0 1 -1\n2 1 1 0 0 1 1\n"),
        ("orphans", "1 1 0 0 0 1 5\n2 1 1 0 0 1 7\n"),
        ("empty", ""),
        ("duplicate-ids", "1 1 0 0 0 1 -1\n1 1 1 0 0 1 1\n"),
        ("negative-radius", "1 1 0 0 0 -1 -1\n2 1 1 0 0 -1 1\n"),
        ("too-few-columns", "1 1 0 0 0 1\n2 1 1 0 0 1\n"),
        ("binary", "\u{0}\u{1}\u{2}\u{ff}\u{fe}garbage\u{7}\n\u{0}"),
        ("one-node", "1 1 0 0 0 1 -1\n"),
        ("only-roots", "1 1 0 0 0 1 -1\n2 1 5 0 0 1 -1\n"),
    ];
    for (name, text) in corpus {
        let file = format!("{name}.swc");
        std::fs::write(dir.join(&file), text).unwrap();
        refused(&dir, &["synth", "--tree", &file, "--out", "out/c"], &[&file]);
    }
    // Vessels far thinner than the voxel: the message says so instead of blaming the file.
    std::fs::write(dir.join("thin.swc"), "1 1 0 0 0 1e-9 -1\n2 1 100 0 0 1e-9 1\n").unwrap();
    refused(&dir, &["synth", "--tree", "thin.swc", "--out", "out/c"], &["thinner than a voxel"]);
    // A tree in metres (a 0.1 mm tree): the message asks for millimetres.
    std::fs::write(dir.join("metres.swc"), "1 1 0 0 0 1e-7 -1\n2 1 0.1 0 0 1e-7 1\n").unwrap();
    refused(&dir, &["synth", "--tree", "metres.swc", "--out", "out/c"], &["spans 0.1000 mm", "in mm?"]);
}

#[test]
fn out_of_range_flags_are_refused_naming_the_flag() {
    let dir = sandbox("synth-flags");
    let base = ["synth", "--out", "out/c", "--terminals", "8", "--detector-px", "64"];
    for (flag, value, expect) in [
        ("--supersample", "100000", "supersample"),
        ("--voxel-mm", "1e-4", "voxel"),
        ("--noise-photons", "0", "noise photons"),
        ("--noise-photons=1e4", "--noise-attenuation=-0.1", "noise attenuation"),
        ("--binning", "1000", "binning"),
        ("--contrast", "nan", "contrast"),
        ("--noise-sigma=-1", "", "noise sigma"),
        ("--views", "angles:1e300", "angle"),
        ("--views", "angles:0,0", "twice"),
        ("--arrival-fps=7.5", "--arrival-frame-noise=-1", "frame noise"),
        ("--arrival-fps=7.5", "--arrival-velocity-spread=inf", "velocity spread"),
        ("--arrival-fps=7.5", "--arrival-interleave=2", "interleave"),
    ] {
        let mut args = base.to_vec();
        args.extend([flag, value].into_iter().filter(|a| !a.is_empty()));
        refused(&dir, &args, &[expect]);
    }
    // Growth is quadratic in the terminals: 10^8 would run for days.
    refused(&dir, &["synth", "--out", "out/c", "--terminals", "100000000"], &["--terminals", "10000 terminals"]);
    // Bench sizes: a billion Gaussians or a 10^5-pixel detector would allocate for minutes, then abort.
    for args in [
        ["bench", "projector", "--voxels", "0"],
        ["bench", "--threads", "100000", "projector"],
        ["bench", "render", "--gaussians", "1000000000"],
        ["bench", "render", "--gaussians", "0"],
        ["bench", "render", "--size", "0"],
        ["bench", "render", "--repeats", "0"],
        ["bench", "train", "--steps", "0"],
        ["bench", "train-suite", "--steps", "1000000000000"],
        // A million cells at a time spawned a million threads and aborted.
        ["experiment", "--list", "--jobs", "1000000"],
        ["experiment", "--list", "--jobs", "0"],
        ["experiment", "--list", "--threads-per-job", "0"],
        ["experiment", "--list", "--threads-per-job", "100000"],
    ] {
        refused(&dir, &args, &[args[args.len() - 2]]);
    }
    // The demo's overrides and folder: checked before the phantom is made.
    std::fs::write(dir.join("a-file"), "mine").unwrap();
    refused(&dir, &["demo", "--out", "out/demo", "--set", "run.iterations=abc"], &["run.iterations=abc"]);
    assert!(!dir.join("out/demo").exists(), "the demo made its phantom before reading its overrides");
    refused(&dir, &["demo", "--out", "a-file"], &["a-file", "is a file"]);
    assert_eq!(std::fs::read_to_string(dir.join("a-file")).unwrap(), "mine");
    // Checked before any file is read or scored.
    refused(&dir, &["eval", "--pred", "a.obj", "--gt", "b.obj", "--topology-voxel-mm", "0"], &["--topology-voxel-mm"]);
    // An island threshold above every component left nothing to score (it printed inf and NaN).
    std::fs::write(dir.join("tri.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    refused(
        &dir,
        &["eval", "--pred", "tri.obj", "--gt", "tri.obj", "--min-island-mm2", "1e9"],
        &["tri.obj", "min_island_mm2"],
    );
    // --json into a folder not there yet: made, and the scores written whole, atomically (it
    // failed after scoring: no such folder).
    let out = Command::new(BIN)
        .current_dir(&dir)
        .args(["eval", "--pred", "tri.obj", "--gt", "tri.obj", "--json", "out/eval/scores.json"])
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("out/eval/scores.json")).unwrap()).unwrap();
    assert!(json["scores"].is_object(), "{json}");
    assert_eq!(std::fs::read_dir(dir.join("out/eval")).unwrap().count(), 1, "no temporary left");
}

#[test]
fn trees_outside_the_views_are_refused_and_cut_offs_named() {
    let dir = sandbox("field-of-view");
    let base = ["synth", "--out", "out/c", "--terminals", "8", "--detector-px", "128"];
    // Moved off every detector (or lost to f64 precision), or imaged with a pose error that does.
    for extra in [
        &["--translate-mm", "300", "0", "0"][..],
        &["--translate-mm", "1e30", "0", "0"][..],
        &["--pose-error-mm", "1e9"][..],
    ] {
        let args: Vec<&str> = base.iter().chain(extra).copied().collect();
        refused(&dir, &args, &["view `", "no vessel projects onto its detector"]);
        assert!(!dir.join("out/c").exists(), "`ctadsa {}` wrote a case of empty views", args.join(" "));
    }
    // Partly off: written, with the share cut off named per view.
    let args: Vec<&str> = base.iter().chain(&["--translate-mm", "25", "0", "0"]).copied().collect();
    let out = Command::new(BIN).current_dir(&dir).args(&args).env("RUST_BACKTRACE", "0").output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        stdout.contains("warning: view `oblique`: ") && stdout.contains("projects outside the detector"),
        "{stdout}"
    );
    assert!(dir.join("out/c/case.json").is_file());
}

#[test]
fn runs_and_checkpoints_that_are_not_there_are_named_once() {
    let dir = sandbox("not-there");
    let case = valid_case().to_str().unwrap().to_string();
    std::fs::create_dir_all(dir.join("half")).unwrap();
    for (args, expect) in [
        (vec!["diagnose", "--case", &case, "--run", "half"], "half: is not a finished run folder"),
        (vec!["diagnose", "--case", &case, "--run", "nowhere"], "nowhere: does not exist"),
        (vec!["report", "half"], "half: is not a finished run folder"),
        (
            vec!["complete", "--case", &case, "--out", "out/r", "--resume", "ckpt-404"],
            "checkpoint `ckpt-404` does not exist",
        ),
        (vec!["ensemble", "--case", &case, "--runs", "half", "nowhere", "--out", "out/e"], "nowhere: "),
        (vec!["ensemble", "--case", &case, "--runs", "half", "./half", "--out", "out/e"], "are the same run"),
        (vec!["ensemble", "--case", &case, "--runs", "half", ".", "--out", "out/e"], "half is not a finished run"),
    ] {
        refused(&dir, &args, &[expect]);
        // The OS's reason, where one is given, is said once (not again as a cause).
        let out = Command::new(BIN).current_dir(&dir).args(&args).env("RUST_BACKTRACE", "0").output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.matches("No such file or directory").count() <= 1, "{stderr}");
    }
    // A missing input file: named with the OS's reason, once.
    let out = Command::new(BIN)
        .current_dir(&dir)
        .args(["eval", "--pred", "absent.obj", "--gt", "absent.obj"])
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("absent.obj: No such file or directory"), "{stderr}");
    assert_eq!(stderr.matches("No such file or directory").count(), 1, "{stderr}");
}

#[test]
fn out_of_range_config_values_are_refused_naming_the_key() {
    let dir = sandbox("config");
    let case = valid_case().to_str().unwrap().to_string();
    let config = quick_config();
    // 20,000 views (an argument stays under Linux's 128 KiB).
    let long_views = format!("run.views=[{}]", (0..20_000).map(|i| i.to_string()).collect::<Vec<_>>().join(","));
    let long_reseeds =
        format!("densify.reseed_at=[{}]", (0..2_000).map(|i| i.to_string()).collect::<Vec<_>>().join(","));
    for (set, key) in [
        ("init.n1=2000000000", "init.n1"),
        ("field.hidden=100000000", "field.hidden"),
        ("output.metric_samples=0", "output.metric_samples"),
        ("run.image_binning=10000", "run.image_binning"),
        ("densify.max_gaussians=1000000000000", "densify.max_gaussians"),
        ("output.voxel_mm=-1", "output.voxel_mm"),
        ("init.mask_threshold=nan", "init.mask_threshold"),
        ("run.iterationz=5", "iterationz"),
        ("field.encoding.log2_table=40", "log2_table"),
        // Values fine as f64 that break the f32 arithmetic they are used in.
        ("optim.epsilon=1e-50", "optim.epsilon"),
        ("model.scale_max_voxels=1e40", "model.scale_max_voxels"),
        // Keys that were not range-checked.
        ("densify.min_density=nan", "densify.min_density"),
        ("init.prior_dilation_px=4000000000", "init.prior_dilation_px"),
        ("init.residual_dilation_px=100000", "init.residual_dilation_px"),
        ("init.track_prior_dilation_px=100000", "init.track_prior_dilation_px"),
        ("densify.clone_scale_voxels=[0, 0]", "densify.clone_scale_voxels"),
        ("loss.fn_tau=nan", "loss.fn_tau"),
        ("loss.fn_margin=-1", "loss.fn_margin"),
        ("optim.field_weight_decay=-1", "optim.field_weight_decay"),
        ("loss.pa_k=1000000000000", "loss.pa_k"),
        // Refused before training, not after it.
        ("output.voxel_mm=0.011", "output.voxel_mm"),
        // One view twice would pass for two directions.
        ("run.views=[0, 0]", "run.views"),
        // A list long enough that checking it for repeats took minutes.
        (long_views.as_str(), "run.views"),
        (long_reseeds.as_str(), "densify.reseed_at"),
        ("densify.reseed_mask_threshold=nan", "densify.reseed_mask_threshold"),
        ("init.seed_spacing_mm=-1", "init.seed_spacing_mm"),
        ("init.track_level=0", "init.track_level"),
        ("init.track_start_mm=nan", "init.track_start_mm"),
        ("init.track_turn_cost=-1", "init.track_turn_cost"),
        ("init.track_max_points=2000000000", "init.track_max_points"),
        ("output.near_prior_mask_threshold=1.5", "output.near_prior_mask_threshold"),
        ("output.near_prior_mm=nan", "output.near_prior_mm"),
    ] {
        refused(&dir, &["complete", "--case", &case, "--config", &config, "--out", "out/run", "--set", set], &[key]);
    }
    std::fs::write(dir.join("bad.toml"), "[run]\niterations = \"many\"\n").unwrap();
    refused(&dir, &["complete", "--case", &case, "--config", "bad.toml", "--out", "out/run"], &["bad.toml"]);
}

/// Edits the valid case's `case.json` with `edit` into `dir/name`.
fn edited_case(dir: &Path, name: &str, edit: impl Fn(&mut serde_json::Value)) -> String {
    let case = dir.join(name);
    copy_dir(valid_case(), &case);
    let path = case.join("case.json");
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    edit(&mut json);
    std::fs::write(&path, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
    name.to_string()
}

#[test]
fn malformed_case_files_are_refused_and_nothing_escapes() {
    let dir = sandbox("case");
    let config = quick_config();
    let cases = [
        edited_case(&dir, "escape-name", |j| j["name"] = "../../escaped".into()),
        edited_case(&dir, "escape-view", |j| j["views"][0]["name"] = "../v".into()),
        edited_case(&dir, "absolute-view", |j| j["views"][1]["name"] = "/tmp/v".into()),
        edited_case(&dir, "negative-png-scale", |j| j["views"][0]["png_scale"] = (-1.0).into()),
        edited_case(&dir, "negative-arrival-offset", |j| j["views"][1]["arrival_offset_frames"] = (-0.5).into()),
        edited_case(&dir, "huge-arrival-offset", |j| j["views"][1]["arrival_offset_frames"] = 1e30.into()),
        edited_case(&dir, "tiny-voxel", |j| j["volume"]["voxel_mm"] = 1e-6.into()),
        edited_case(&dir, "huge-box", |j| j["volume"]["max_mm"] = serde_json::json!([1e300, 1e300, 1e300])),
        edited_case(&dir, "wrong-version", |j| j["version"] = 99.into()),
        edited_case(&dir, "no-views", |j| j["views"] = serde_json::json!([])),
        edited_case(&dir, "bad-geometry", |j| j["views"][0]["geometry"]["dso_mm"] = 0.0.into()),
        edited_case(&dir, "angle-past-a-turn", |j| j["views"][0]["geometry"]["primary_deg"] = 1e300.into()),
        edited_case(&dir, "duplicate-view-names", |j| j["views"][1]["name"] = j["views"][0]["name"].clone()),
        // More views than are read, and detectors too large together: refused before any image
        // is read (each view may name the same 2 GiB file).
        edited_case(&dir, "too-many-views", |j| {
            let view = j["views"][0].clone();
            j["views"] = (0..65)
                .map(|i| {
                    let mut v = view.clone();
                    v["name"] = format!("v{i}").into();
                    v
                })
                .collect();
        }),
        edited_case(&dir, "huge-detectors", |j| {
            for v in j["views"].as_array_mut().unwrap() {
                v["geometry"]["detector_px"] = serde_json::json!([32768, 32768]);
            }
        }),
    ];
    for case in &cases {
        refused(&dir, &["complete", "--case", case, "--config", &config, "--out", "out/run"], &["case.json"]);
    }
    // The folder holding those cases given as a case: named as a folder of cases.
    refused(
        &dir,
        &["complete", "--case", ".", "--config", &config, "--out", "out/run"],
        &["not a case folder", "absolute-view, angle-past-a-turn, bad-geometry and"],
    );
    let cut = dir.join("truncated");
    copy_dir(valid_case(), &cut);
    let text = std::fs::read(cut.join("case.json")).unwrap();
    std::fs::write(cut.join("case.json"), &text[..text.len() / 2]).unwrap();
    refused(&dir, &["complete", "--case", "truncated", "--config", &config, "--out", "out/run"], &["case.json"]);
    // A view image that is not an image.
    let img = dir.join("bad-image");
    copy_dir(valid_case(), &img);
    std::fs::write(img.join("views/ap.tiff"), b"not a tiff").unwrap();
    refused(&dir, &["complete", "--case", "bad-image", "--config", &config, "--out", "out/run"], &["ap.tiff"]);
    // A blank view (every pixel 0): nothing to fit, refused naming the image.
    let blank = dir.join("blank-image");
    copy_dir(valid_case(), &blank);
    let ap = blank.join("views/ap.tiff");
    let tiff = ctadsa_core::data::case::images::read_tiff(&ap).unwrap();
    let zeros = ctadsa_core::data::case::images::Image { data: vec![0.0; tiff.data.len()], ..tiff };
    ctadsa_core::data::case::images::write_tiff_f32(&ap, &zeros).unwrap();
    refused(
        &dir,
        &["complete", "--case", "blank-image", "--config", &config, "--out", "out/run"],
        &["ap.tiff", "no positive pixel"],
    );
    // A prior in another frame (shifted 300 mm): refused before a working box spans both.
    let shifted = dir.join("shifted-prior");
    copy_dir(valid_case(), &shifted);
    let prior = shifted.join("priors/d1p50mm/prior.obj");
    let moved: String = std::fs::read_to_string(&prior)
        .unwrap()
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(xyz) => {
                let v: Vec<f64> = xyz.split_whitespace().map(|t| t.parse().unwrap()).collect();
                format!("v {} {} {}\n", v[0] + 300.0, v[1] + 300.0, v[2])
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&prior, moved).unwrap();
    refused(
        &dir,
        &["complete", "--case", "shifted-prior", "--config", &config, "--out", "out/run"],
        &["prior.obj", "world coordinates"],
    );
    // A view image that is a link to a device or a FIFO: refused before it is opened (reading
    // /dev/zero would never end, opening a FIFO would wait for a writer for ever).
    for (name, target) in [("image-dev-zero", PathBuf::from("/dev/zero")), ("image-fifo", dir.join("a-fifo"))] {
        if name == "image-fifo" && !make_fifo(&target) {
            continue;
        }
        let case = dir.join(name);
        copy_dir(valid_case(), &case);
        std::fs::remove_file(case.join("views/ap.tiff")).unwrap();
        std::os::unix::fs::symlink(&target, case.join("views/ap.tiff")).unwrap();
        refused(
            &dir,
            &["complete", "--case", name, "--config", &config, "--out", "out/run"],
            &["ap.tiff", "regular file"],
        );
    }
}

#[test]
fn runs_do_not_write_over_files_they_did_not_make() {
    let dir = sandbox("out-folder");
    let config = quick_config();
    let case = dir.join("case");
    copy_dir(valid_case(), &case);
    // A folder of the user's with a mesh of the name a run writes, and no run: refused, kept.
    std::fs::create_dir_all(dir.join("mine")).unwrap();
    std::fs::write(dir.join("mine/mesh.obj"), "my own mesh\n").unwrap();
    let run = |out: &str| {
        Command::new(BIN)
            .current_dir(&dir)
            .args(["complete", "--case", "case", "--config", &config, "--out", out, "--set", "run.iterations=2"])
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap()
    };
    let out = run("mine");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("`mesh.obj`") && stderr.contains("--overwrite"), "{stderr}");
    assert_eq!(std::fs::read_to_string(dir.join("mine/mesh.obj")).unwrap(), "my own mesh\n");
    // A folder another live process runs in (process 1 always exists): refused, naming it.
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    std::fs::create_dir_all(dir.join("busy")).unwrap();
    std::fs::write(dir.join("busy/run.lock"), format!("pid 1 on {}", host.trim())).unwrap();
    let out = run("busy");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("being run by pid 1"), "{stderr}");
    // The case folder itself is never a run's folder.
    let before = files_under(&case);
    let out = run("case");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("is a case folder"), "{stderr}");
    assert_eq!(files_under(&case), before, "files appeared in the case folder");
}

/// `ctadsa synth` into a folder that holds a case: refused (the case kept) unless --overwrite,
/// which replaces the case's own files and keeps the user's; a replacement that is itself refused
/// leaves the old case as it was.
#[test]
fn synth_replaces_a_case_only_when_asked() {
    let dir = sandbox("synth-over");
    let synth = |extra: &[&str]| {
        Command::new(BIN)
            .current_dir(&dir)
            .args(["synth", "--out", "c", "--terminals", "8", "--detector-px", "128"])
            .args(extra)
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap()
    };
    let first = synth(&["--prior-diameter", "1.0,1.5"]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    std::fs::write(dir.join("c/notes.txt"), "mine").unwrap();
    let case_json = std::fs::read(dir.join("c/case.json")).unwrap();
    let again = synth(&["--seed", "2"]);
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success() && stderr.contains("already holds a case") && stderr.contains("--overwrite"));
    assert_eq!(std::fs::read(dir.join("c/case.json")).unwrap(), case_json, "the case was touched");
    // A replacement refused by its own checks (a tree off the detectors) keeps the old case.
    let off = synth(&["--overwrite", "--translate-mm", "300", "0", "0"]);
    assert!(!off.status.success());
    assert_eq!(std::fs::read(dir.join("c/case.json")).unwrap(), case_json, "a refused replacement removed the case");
    assert!(dir.join("c/priors/d1p50mm/prior.obj").exists());
    let replaced = synth(&["--overwrite", "--seed", "2", "--prior-diameter", "1.0"]);
    assert!(replaced.status.success(), "{}", String::from_utf8_lossy(&replaced.stderr));
    assert_ne!(std::fs::read(dir.join("c/case.json")).unwrap(), case_json);
    assert!(!dir.join("c/priors/d1p50mm").exists(), "a prior of the old case survived its replacement");
    assert_eq!(std::fs::read_to_string(dir.join("c/notes.txt")).unwrap(), "mine", "a file of the user's removed");
}

/// A FIFO at `path` (`mkfifo`); false where the tool is missing.
fn make_fifo(path: &Path) -> bool {
    let _ = std::fs::remove_file(path);
    Command::new("mkfifo").arg(path).status().is_ok_and(|s| s.success())
}

#[test]
fn malformed_meshes_are_refused_naming_the_file() {
    let dir = sandbox("obj");
    let corpus: &[(&str, &str)] = &[
        ("index-out-of-range", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"),
        ("nan-vertex", "v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
        ("no-faces", "v 0 0 0\nv 1 0 0\n"),
        ("garbage", "\u{0}\u{1}this is not a mesh\n"),
        // A negative texture index past the list: an overflow panic inside tobj.
        ("negative-texture-index", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/-5 2/-5 3/-5\n"),
        // Side references are not followed: with the material library ignored, no faces remain.
        ("mtllib-dev-zero", "mtllib /dev/zero\nv 0 0 0\nv 1 0 0\n"),
    ];
    let gt = valid_case().join("gt/complete.obj");
    for (name, text) in corpus {
        let file = format!("{name}.obj");
        std::fs::write(dir.join(&file), text).unwrap();
        refused(&dir, &["eval", "--pred", &file, "--gt", gt.to_str().unwrap()], &[&file]);
    }
    refused(
        &dir,
        &["eval", "--pred", gt.to_str().unwrap(), "--gt", gt.to_str().unwrap(), "--samples", "2e9"],
        &["--samples"],
    );
    // A mesh that is a device or a FIFO.
    std::os::unix::fs::symlink("/dev/zero", dir.join("dev-zero.obj")).unwrap();
    refused(&dir, &["eval", "--pred", "dev-zero.obj", "--gt", gt.to_str().unwrap()], &["dev-zero.obj", "regular file"]);
    if make_fifo(&dir.join("fifo.obj")) {
        refused(&dir, &["eval", "--pred", "fifo.obj", "--gt", gt.to_str().unwrap()], &["fifo.obj", "regular file"]);
    }
    // A material library that names a FIFO is not opened: the mesh itself is read.
    if make_fifo(&dir.join("materials.mtl")) {
        let text = std::fs::read_to_string(&gt).unwrap();
        std::fs::write(dir.join("with-mtllib.obj"), format!("mtllib materials.mtl\n{text}")).unwrap();
        let out = Command::new(BIN)
            .current_dir(&dir)
            .args(["eval", "--pred", "with-mtllib.obj", "--gt", gt.to_str().unwrap(), "--samples", "2000"])
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
}

/// A NIfTI-1 single file (`.nii`): header fields as given, `data` after the 352-byte offset.
fn nifti(
    dims: [i16; 3],
    datatype: i16,
    bitpix: i16,
    pixdim: [f32; 3],
    quatern: Option<[f32; 3]>,
    data: &[u8],
) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    let put = |h: &mut Vec<u8>, at: usize, b: &[u8]| h[at..at + b.len()].copy_from_slice(b);
    put(&mut h, 0, &348i32.to_le_bytes());
    let dim = [3i16, dims[0], dims[1], dims[2], 1, 1, 1, 1];
    for (k, d) in dim.iter().enumerate() {
        put(&mut h, 40 + 2 * k, &d.to_le_bytes());
    }
    put(&mut h, 70, &datatype.to_le_bytes());
    put(&mut h, 72, &bitpix.to_le_bytes());
    let pd = [1.0f32, pixdim[0], pixdim[1], pixdim[2], 1.0, 1.0, 1.0, 1.0];
    for (k, p) in pd.iter().enumerate() {
        put(&mut h, 76 + 4 * k, &p.to_le_bytes());
    }
    put(&mut h, 108, &352f32.to_le_bytes());
    put(&mut h, 112, &1f32.to_le_bytes());
    if let Some(q) = quatern {
        put(&mut h, 252, &1i16.to_le_bytes());
        for (k, v) in q.iter().enumerate() {
            put(&mut h, 256 + 4 * k, &v.to_le_bytes());
        }
    }
    put(&mut h, 344, b"n+1\0");
    h.extend_from_slice(data);
    h
}

#[test]
fn malformed_nifti_volumes_are_refused_naming_the_field() {
    let dir = sandbox("nifti");
    let n = 4usize;
    let labels: Vec<u8> = (0..n * n * n).map(|i| u8::from(i % 3 == 0)).collect();
    let rgb: Vec<u8> = labels.iter().flat_map(|&v| [v, v, v]).collect();
    let corpus: Vec<(&str, Vec<u8>, &str)> = vec![
        ("rgb24", nifti([4; 3], 128, 24, [1.0; 3], None, &rgb), "datatype"),
        ("nan-pixdim", nifti([4; 3], 2, 8, [f32::NAN, 1.0, 1.0], None, &labels), "pixdim"),
        ("zero-pixdim", nifti([4; 3], 2, 8, [0.0, 1.0, 1.0], None, &labels), "pixdim"),
        ("non-unit-quaternion", nifti([4; 3], 2, 8, [1.0; 3], Some([3.0, 0.0, 0.0]), &labels), "quatern"),
        ("huge-dims", nifti([32767; 3], 2, 8, [1.0; 3], None, &labels), "dim"),
        ("negative-dims", nifti([4, -4, 4], 2, 8, [1.0; 3], None, &labels), "dim"),
        ("truncated", nifti([4; 3], 2, 8, [1.0; 3], None, &labels[..10]), "truncated"),
    ];
    for (name, bytes, field) in &corpus {
        let file = format!("{name}.nii");
        std::fs::write(dir.join(&file), bytes).unwrap();
        let expect: &[&str] = if *name == "truncated" { &[&file] } else { &[&file, field] };
        refused(&dir, &["prior", "--labels", &file, "--out", "out/prior.obj"], expect);
    }
    // A valid volume (a 4 mm cube of label 1) shifted beside a case's field: refused with --case.
    let n = 8usize;
    let cube: Vec<u8> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, i / n % n, i / (n * n));
            u8::from([x, y, z].iter().all(|c| (2..6).contains(c)))
        })
        .collect();
    std::fs::write(dir.join("cube.nii"), nifti([8; 3], 2, 8, [1.0; 3], None, &cube)).unwrap();
    let case = valid_case().to_str().unwrap().to_string();
    let args = ["prior", "--labels", "cube.nii", "--case", &case, "--visible", "all", "--out", "out/prior.obj"];
    refused(&dir, &[&args[..], &["--prior-shift-mm", "300", "300", "0"]].concat(), &["cube.nii", "world coordinates"]);
    // Without --case there is nothing to check a shift against: a shift past 10 m is refused
    // (1e300 wrote a mesh of 1e300 mm coordinates), and the mesh format before any work.
    refused(
        &dir,
        &["prior", "--labels", "cube.nii", "--out", "out/prior.obj", "--prior-shift-mm", "1e300", "0", "0"],
        &["--prior-shift-mm", "10000 mm"],
    );
    refused(&dir, &["prior", "--labels", "cube.nii", "--out", "out/prior.txt"], &["out/prior.txt", "extension"]);
    // A simulated DSA run whose darkest pixels would fall to a few 16-bit counts, or no contrast.
    for peak in ["0", "1e30"] {
        refused(
            &dir,
            &["export-dicom", "--case", &case, "--out", "out/xa", "--peak-attenuation", peak],
            &["peak attenuation", "(0, 5]"],
        );
    }
}

/// Replaces the value of an explicit-VR little-endian element `(group, element)` of 2-byte
/// length in a DICOM file.
fn patch_element(bytes: &mut [u8], group: u16, element: u16, value: [u8; 2]) {
    let tag = [group.to_le_bytes(), element.to_le_bytes()].concat();
    let at = bytes[132..].windows(4).position(|w| w == tag.as_slice()).expect("tag present") + 132;
    assert_eq!(&bytes[at + 6..at + 8], &[2, 0], "2-byte value");
    bytes[at + 8..at + 10].copy_from_slice(&value);
}

#[test]
fn malformed_dicom_runs_are_refused_naming_the_tag() {
    let dir = sandbox("dicom");
    let exported = Command::new(BIN)
        .args(["export-dicom", "--case", valid_case().to_str().unwrap(), "--out"])
        .arg(dir.join("xa"))
        .output()
        .unwrap();
    assert!(exported.status.success(), "{}", String::from_utf8_lossy(&exported.stderr));
    let good = std::fs::read(dir.join("xa/ap.dcm")).unwrap();
    let mut huge = good.clone();
    patch_element(&mut huge, 0x0028, 0x0010, [0xff, 0xff]); // Rows
    patch_element(&mut huge, 0x0028, 0x0011, [0xff, 0xff]); // Columns
    patch_element(&mut huge, 0x0028, 0x0008, *b"99"); // Number of Frames
    std::fs::write(dir.join("huge.dcm"), &huge).unwrap();
    refused(&dir, &["import-dsa", "--run", "huge.dcm", "--out", "out/case"], &["huge.dcm", "pixels; at most"]);
    let mut taller = good.clone();
    patch_element(&mut taller, 0x0028, 0x0010, 1024u16.to_le_bytes()); // Rows: 4× the pixels stored
    std::fs::write(dir.join("taller.dcm"), &taller).unwrap();
    refused(&dir, &["import-dsa", "--run", "taller.dcm", "--out", "out/case"], &["taller.dcm", "Pixel Data holds"]);
    let mut frames = good.clone();
    patch_element(&mut frames, 0x0028, 0x0008, *b"x "); // Number of Frames
    std::fs::write(dir.join("frames.dcm"), &frames).unwrap();
    refused(&dir, &["import-dsa", "--run", "frames.dcm", "--out", "out/case"], &["frames.dcm", "Number of Frames"]);
    // A Pixel Data length field claiming 4 GiB in a 1 MB file: refused from the headers, before
    // the parser reserves what the field claims.
    let at = good.windows(6).position(|w| w == [0xE0, 0x7F, 0x10, 0x00, b'O', b'W']).unwrap();
    let mut claims = good.clone();
    claims[at + 8..at + 12].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    std::fs::write(dir.join("claims.dcm"), &claims).unwrap();
    refused(&dir, &["import-dsa", "--run", "claims.dcm", "--out", "out/case"], &["claims.dcm", "(7FE0,0010)"]);
    std::fs::write(dir.join("cut.dcm"), &good[..good.len() / 2]).unwrap();
    refused(&dir, &["import-dsa", "--run", "cut.dcm", "--out", "out/case"], &["cut.dcm"]);
    std::fs::write(dir.join("not.dcm"), b"hello").unwrap();
    refused(&dir, &["import-dsa", "--run", "not.dcm", "--out", "out/case"], &["not.dcm"]);
    std::fs::copy(dir.join("xa/ap.dcm"), dir.join("ok.dcm")).unwrap();
    refused(
        &dir,
        &["import-dsa", "--run", "ok.dcm", "--out", "out/case", "--curve-fraction", "NaN"],
        &["curve fraction"],
    );
    refused(&dir, &["import-dsa", "--run", "ok.dcm", "--out", "out/case", "--binning", "100000"], &["binning"]);
    // A prior mesh in another frame (300 mm beside the views' field): refused before the case
    // is written.
    std::fs::write(dir.join("beside.obj"), "v 300 300 0\nv 301 300 0\nv 300 301 0\nf 1 2 3\n").unwrap();
    refused(
        &dir,
        &["import-dsa", "--run", "ok.dcm", "--prior", "beside.obj", "--out", "out/case"],
        &["beside.obj", "world coordinates"],
    );
    assert!(!dir.join("out/case").exists(), "a case was written with a prior outside the views");
    // One run given twice (one direction twice), and a working volume too large: refused before
    // anything is written.
    for (args, expect) in [
        (&["--run", "ok.dcm", "--run", "ok.dcm"][..], "have the same geometry"),
        (&["--run", "ok.dcm", "--voxel-mm", "1e-4"][..], "raise the voxel size"),
        // A voxel larger than the working box: a grid that cannot hold a vessel.
        (&["--run", "ok.dcm", "--voxel-mm", "1e9"][..], "coarser than the working box"),
        // Options that shape a label prior, with a mesh prior (or none): they would be ignored.
        (
            &["--run", "ok.dcm", "--prior", "beside.obj", "--label-ids", "3"][..],
            "--label-ids shapes a prior made from --labels",
        ),
        (&["--run", "ok.dcm", "--min-island-mm2", "5"][..], "--min-island-mm2 shapes a prior"),
        (&["--run", "ok.dcm", "--prior-shift-mm", "1", "2", "3"][..], "--prior-shift-mm shapes a prior"),
        (&["--run", "ok.dcm", "--visible", "any"][..], "--visible shapes a prior"),
        (&["--run", "ok.dcm", "--visible", "some"][..], "possible values: all, every, any"),
        (&["--run", "ok.dcm", "--min-island-mm2", "NaN"][..], "NaN is not an area"),
    ] {
        let all: Vec<&str> = ["import-dsa", "--out", "out/case"].iter().chain(args).copied().collect();
        refused(&dir, &all, &[expect]);
        assert!(!dir.join("out/case").exists(), "`ctadsa {}` wrote a case that would not load", all.join(" "));
    }
}

#[test]
fn malformed_experiment_names_do_not_escape() {
    let dir = sandbox("experiment");
    let config = quick_config();
    std::fs::write(
        dir.join("matrix.toml"),
        format!(
            "views = [[0, 1]]\npriors = []\nset = []\n[[methods]]\nname = \"../../escaped\"\nconfig = \"{config}\"\n"
        ),
    )
    .unwrap();
    let case = valid_case().to_str().unwrap().to_string();
    refused(&dir, &["experiment", "--matrix", "matrix.toml", "--cases", &case, "--out", "out/m"], &["matrix.toml"]);
    // 256 jobs of 1,024 kernel threads each would start 262,144 threads.
    refused(
        &dir,
        &[
            "experiment",
            "--matrix",
            "matrix.toml",
            "--cases",
            &case,
            "--out",
            "out/m",
            "--jobs",
            "256",
            "--threads-per-job",
            "1024",
        ],
        &["--jobs 256", "--threads-per-job 1024", "4096"],
    );
    // A view the case does not have: refused when the matrix is read, not in each cell.
    std::fs::write(
        dir.join("views.toml"),
        format!("views = [[0, 1], [0, 5]]\npriors = []\nset = []\n[[methods]]\nname = \"m\"\nconfig = \"{config}\"\n"),
    )
    .unwrap();
    refused(
        &dir,
        &["experiment", "--matrix", "views.toml", "--cases", &case, "--out", "out/m", "--list"],
        &["views.toml", "[0, 5]", "it has 3"],
    );
    // An empty view subset (a run's "all views") and a prior the case lacks: refused up front too.
    for (file, matrix, expect) in [
        ("empty.toml", "views = [[]]\npriors = []\n", &["empty.toml", "empty view subset"][..]),
        ("prior.toml", "views = [[0, 1]]\npriors = [\"d9p99mm\"]\n", &["prior.toml", "no prior `d9p99mm`"][..]),
        // A bad value from the matrix's `set` is named as an override, not as the method's file.
        (
            "set.toml",
            "views = [[0, 1]]\npriors = []\nset = [\"run.iterations=-5\"]\n",
            &["override `run.iterations=-5`"][..],
        ),
    ] {
        std::fs::write(dir.join(file), format!("{matrix}[[methods]]\nname = \"m\"\nconfig = \"{config}\"\n")).unwrap();
        refused(&dir, &["experiment", "--matrix", file, "--cases", &case, "--out", "out/m", "--list"], expect);
    }
    // An ensemble of a method the matrix lacks; an ensemble cell run before its members.
    let ensemble = |of: &str| {
        format!(
            "views = [[0, 1]]\n[[methods]]\nname = \"m\"\nconfig = \"{config}\"\n[[methods]]\nname = \"n\"\n\
             config = \"{config}\"\nset = [\"run.seed=7\"]\n[[ensembles]]\nname = \"e\"\nmethods = [{of}]\n"
        )
    };
    std::fs::write(dir.join("ensemble.toml"), ensemble("\"m\", \"x\"")).unwrap();
    refused(
        &dir,
        &["experiment", "--matrix", "ensemble.toml", "--cases", &case, "--out", "out/m", "--list"],
        &["ensemble.toml", "`x`, which is no method of the matrix"],
    );
    std::fs::write(dir.join("ensemble.toml"), ensemble("\"m\", \"n\"")).unwrap();
    refused(
        &dir,
        &["experiment", "--matrix", "ensemble.toml", "--cases", &case, "--out", "out/e", "--cell", "2"],
        &["cell 2", "ensemble e", "not finished", "0 (", "1 ("],
    );
    // A matrix of a million cells is refused before any cell's configuration is read.
    let subsets = (0..1000).map(|i| format!("[{i}]")).collect::<Vec<_>>().join(", ");
    let methods =
        (0..1000).map(|i| format!("[[methods]]\nname = \"m{i}\"\nconfig = \"{config}\"\n")).collect::<String>();
    std::fs::write(dir.join("huge.toml"), format!("views = [{subsets}]\npriors = []\nset = []\n{methods}")).unwrap();
    refused(
        &dir,
        &["experiment", "--matrix", "huge.toml", "--cases", &case, "--out", "out/m", "--list"],
        &["huge.toml", "1000000 cells", "at most 100000"],
    );
    // `--list | head -1`: the reader leaves after one line; the listing stops quietly.
    let methods =
        (0..300).map(|i| format!("[[methods]]\nname = \"m{i}\"\nconfig = \"{config}\"\n")).collect::<String>();
    std::fs::write(
        dir.join("long.toml"),
        format!("views = [[0, 1], [0, 2], [1, 2]]\npriors = []\nset = []\n{methods}"),
    )
    .unwrap();
    let out = Command::new("sh")
        .current_dir(&dir)
        .env("RUST_BACKTRACE", "0")
        .arg("-c")
        .arg(format!("'{BIN}' experiment --matrix long.toml --cases '{case}' --out out/m --list | head -1"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("0\ttodo\t"), "{stderr}");
    assert!(!stderr.contains("panicked") && !stderr.contains("Broken pipe"), "{stderr}");
}
