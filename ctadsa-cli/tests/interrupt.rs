//! A run stopped by SIGTERM (what `timeout`, SLURM and `docker stop` send) saves a checkpoint
//! and exits non-zero; `--resume` finishes it.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

mod common;
use common::{BIN, small_case, tmp};

/// `ctadsa complete` on `case` into `run` with the quick config shrunk: `iterations`, a
/// checkpoint every `every` steps, `n1` + `n2` Gaussians, no densification, no prior-only
/// member; then `extra`.
fn complete_cmd(
    case: &std::path::Path,
    run: &std::path::Path,
    iterations: usize,
    every: usize,
    (n1, n2): (usize, usize),
    extra: &[&str],
) -> Command {
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
    let mut c = Command::new(BIN);
    c.args(["complete", "--case", case.to_str().unwrap(), "--config", config, "--out", run.to_str().unwrap()]);
    for s in [
        format!("run.iterations={iterations}"),
        format!("run.checkpoint_every={every}"),
        format!("init.n1={n1}"),
        format!("init.n2={n2}"),
        "densify.enabled=false".into(),
        "output.metric_samples=2000".into(),
        "run.prior_only_member=false".into(),
    ] {
        c.args(["--set", &s]);
    }
    c.args(extra).env("RUST_BACKTRACE", "0");
    c
}

#[test]
fn sigterm_saves_a_checkpoint_exits_non_zero_and_resume_finishes() {
    let (case, run) = (tmp("term-case"), tmp("term-run"));
    let bin = BIN;
    small_case(&case);
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
    let args = |extra: &[&str]| {
        let mut a: Vec<String> =
            ["complete", "--case", case.to_str().unwrap(), "--config", config].iter().map(|s| s.to_string()).collect();
        a.extend(["--out", run.to_str().unwrap()].map(String::from));
        a.extend(
            [
                "run.iterations=100000",
                "init.n1=500",
                "init.n2=300",
                "densify.enabled=false",
                "output.metric_samples=2000",
                "run.prior_only_member=false",
            ]
            .iter()
            .flat_map(|s| ["--set".to_string(), s.to_string()]),
        );
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    // Without a terminal the loop logs a line after its first step: stop it then.
    let mut child = Command::new(bin).args(args(&[])).stderr(Stdio::piped()).spawn().unwrap();
    let stderr = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    for line in stderr.lines() {
        let line = line.unwrap();
        seen += &line;
        seen.push('\n');
        if line.starts_with("[") {
            let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
            assert!(kill.success());
            break;
        }
    }
    let status = child.wait().unwrap();
    assert!(!status.success(), "an interrupted run must exit non-zero; log:\n{seen}");
    let checkpoints: Vec<_> = std::fs::read_dir(run.join("checkpoints")).unwrap().collect();
    assert_eq!(checkpoints.len(), 1, "one checkpoint saved on SIGTERM");
    assert!(!run.join("summary.json").exists(), "no outputs for an unfinished run");
    // Resume with a reachable end.
    let mut resume = args(&["--resume"]);
    let at = resume.iter().position(|a| a == "run.iterations=100000").unwrap();
    resume[at] = "run.iterations=30".into();
    let out = Command::new(bin).args(&resume).output().unwrap();
    assert!(out.status.success(), "resume failed:\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("resuming from"));
    assert!(run.join("summary.json").exists() && run.join("mesh.obj").exists());
}

/// A folder holding a run is not overwritten by accident, a resume with other settings is
/// refused, and a checkpoint cut short (a kill while it was written by an older version, a full
/// disk) is skipped for the previous one.
#[test]
fn run_folder_is_protected_and_resume_falls_back_to_a_good_checkpoint() {
    let (case, run) = (tmp("fold-case"), tmp("fold-run"));
    small_case(&case);
    let complete = |iterations: usize, extra: &[&str]| {
        complete_cmd(&case, &run, iterations, 2, (300, 200), extra).output().unwrap()
    };
    let first = complete(4, &[]);
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let summary = std::fs::read(run.join("summary.json")).unwrap();

    let again = complete(4, &[]);
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success() && err.contains("already holds a run") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read(run.join("summary.json")).unwrap(), summary, "the finished run was touched");

    let other = complete(6, &["--resume", "--set", "init.n1=400"]);
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(!other.status.success() && err.contains("init.n1") && err.contains("other settings"), "{err}");

    // Cut the newest checkpoint's model short: the resume warns and continues from the one before.
    let newest = run.join("checkpoints/ckpt-0000004/model.bpk");
    let bytes = std::fs::read(&newest).unwrap();
    std::fs::write(&newest, &bytes[..bytes.len() / 3]).unwrap();
    let resumed = complete(6, &["--resume"]);
    let err = String::from_utf8_lossy(&resumed.stderr);
    assert!(resumed.status.success(), "{err}");
    assert!(err.contains("ckpt-0000004") && err.contains("unusable") && err.contains("ckpt-0000002"), "{err}");
    let state: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("checkpoints/ckpt-0000006/state.json")).unwrap()).unwrap();
    assert_eq!(state["iteration"], 6);

    // A checkpoint whose state claims more Gaussians than its model file holds is refused.
    let state_path = run.join("checkpoints/ckpt-0000006/state.json");
    let text = std::fs::read_to_string(&state_path).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["gaussians"] = serde_json::json!(1_000_000_000_000u64);
    std::fs::write(&state_path, serde_json::to_string(&v).unwrap()).unwrap();
    let ck = run.join("checkpoints/ckpt-0000006");
    let bad = complete(8, &["--resume", ck.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && !err.contains("panicked") && err.contains("state.json"), "{err}");
    // So is one whose step count disagrees with its loss history (a run past its end would
    // write outputs without training), or whose seed counts are absurd.
    for (key, value, expect) in [
        ("iteration", serde_json::json!(u64::MAX), "the loss history ends at step 6"),
        ("n1", serde_json::json!(u64::MAX), "`n1`"),
    ] {
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v[key] = value;
        std::fs::write(&state_path, serde_json::to_string(&v).unwrap()).unwrap();
        let bad = complete(8, &["--resume", ck.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&bad.stderr);
        assert!(!bad.status.success() && err.contains("state.json") && err.contains(expect), "{err}");
    }

    // --overwrite clears what the earlier run wrote (an output this run does not write again
    // must not survive beside the new ones) and keeps what the user put in the folder.
    std::fs::write(run.join("poses.json"), "{}").unwrap();
    std::fs::write(run.join("mesh.stl"), "old").unwrap();
    std::fs::write(run.join("notes.txt"), "mine").unwrap();
    let fresh = complete(2, &["--overwrite"]);
    assert!(fresh.status.success(), "{}", String::from_utf8_lossy(&fresh.stderr));
    assert!(!run.join("checkpoints/ckpt-0000006").exists(), "--overwrite leaves the old run's checkpoints");
    assert!(run.join("checkpoints/ckpt-0000002").exists());
    assert!(!run.join("poses.json").exists() && !run.join("mesh.stl").exists(), "old outputs left beside the new");
    assert_eq!(std::fs::read_to_string(run.join("notes.txt")).unwrap(), "mine", "a file of the user's removed");
}

/// SIGKILL gives no chance to save: the run resumes from its last periodic checkpoint (written
/// atomically, so a kill while one is written leaves only complete ones) and finishes.
#[test]
fn sigkill_resumes_from_the_last_periodic_checkpoint() {
    let (case, run) = (tmp("kill-case"), tmp("kill-run"));
    small_case(&case);
    let complete = |iterations: usize, extra: &[&str]| complete_cmd(&case, &run, iterations, 3, (500, 300), extra);
    let mut child = complete(100_000, &[]).stderr(Stdio::null()).spawn().unwrap();
    let checkpoints = run.join("checkpoints");
    let started = std::time::Instant::now();
    while checkpoints_in(&checkpoints) < 2 {
        assert!(started.elapsed().as_secs() < 300, "no periodic checkpoint after 300 s");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.kill().unwrap(); // SIGKILL
    let status = child.wait().unwrap();
    assert!(!status.success());
    assert!(!run.join("summary.json").exists());
    let saved = checkpoints_in(&checkpoints);
    let out = complete(3 * saved + 3, &["--resume"]).output().unwrap();
    assert!(out.status.success(), "resume after SIGKILL failed:\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(run.join("summary.json").exists() && run.join("mesh.obj").exists());
    let leftovers: Vec<_> = std::fs::read_dir(&checkpoints)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_str().is_some_and(|n| n.contains(".partial-")))
        .collect();
    assert!(leftovers.is_empty(), "half-written checkpoint folders left behind: {leftovers:?}");
}

/// Complete checkpoint folders (`ckpt-…`, not a temporary `.ckpt-….partial`) in `dir`.
fn checkpoints_in(dir: &std::path::Path) -> usize {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries.flatten().filter(|e| e.file_name().to_str().is_some_and(|n| n.starts_with("ckpt-"))).count()
        })
        .unwrap_or(0)
}

/// SIGTERM after training, while the outputs are written (here made long by many metric
/// samples): nothing is left to checkpoint, so the process ends at once with code 130 instead of
/// finishing the phase.
#[test]
fn sigterm_while_writing_outputs_ends_the_process_at_once() {
    let (case, run) = (tmp("term-out-case"), tmp("term-out-run"));
    small_case(&case);
    let mut child = complete_cmd(&case, &run, 2, 0, (300, 200), &["--set", "output.metric_samples=10000000"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    for line in stderr.lines() {
        let line = line.unwrap();
        seen += &line;
        seen.push('\n');
        // The last step's log line: training is over, the outputs begin.
        if line.starts_with('[') && line.contains("2/2]") {
            break;
        }
    }
    std::thread::sleep(std::time::Duration::from_millis(500));
    let sent = std::time::Instant::now();
    let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    let waited = sent.elapsed();
    assert_eq!(status.code(), Some(130), "exit status {status:?}; log:\n{seen}");
    assert!(waited.as_secs() < 10, "took {waited:?} to stop");
    assert!(!run.join("summary.json").exists(), "the outputs were not finished");
    assert_eq!(checkpoints_in(&run.join("checkpoints")), 1, "the final checkpoint stays");
}

/// SIGTERM while the Gaussians are initialised (here made long by three million of them on the
/// prior): no step has run, nothing to checkpoint; the process ends within 10 s, non-zero.
#[test]
fn sigterm_during_initialisation_ends_the_process() {
    let (case, run) = (tmp("term-init-case"), tmp("term-init-run"));
    small_case(&case);
    let mut child = complete_cmd(&case, &run, 2, 0, (3_000_000, 200), &[]).stderr(Stdio::piped()).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let sent = std::time::Instant::now();
    let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    let waited = sent.elapsed();
    let mut log = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut log).unwrap();
    assert!(!log.contains("1/2]"), "initialisation was over before the signal; log:\n{log}");
    assert_ne!(status.code(), Some(0), "exit status {status:?}; log:\n{log}");
    assert!(status.code().is_some(), "ended by its own handler, not killed: {status:?}");
    assert!(waited.as_secs() < 10, "took {waited:?} to stop");
    assert!(!run.join("summary.json").exists());
}
