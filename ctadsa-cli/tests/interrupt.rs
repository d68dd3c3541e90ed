//! A run stopped by SIGTERM (what `timeout`, SLURM and `docker stop` send) saves a checkpoint
//! and exits non-zero; `--resume` finishes it.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};

fn tmp(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("cli-{name}-{}", std::process::id()))
}

#[test]
fn sigterm_saves_a_checkpoint_exits_non_zero_and_resume_finishes() {
    let (case, run) = (tmp("term-case"), tmp("term-run"));
    let bin = env!("CARGO_BIN_EXE_ctadsa");
    let synth = Command::new(bin)
        .args(["synth", "--out", case.to_str().unwrap(), "--terminals", "16", "--detector-px", "96"])
        .args(["--binning", "2", "--voxel-mm", "0.6"])
        .output()
        .unwrap();
    assert!(synth.status.success(), "{}", String::from_utf8_lossy(&synth.stderr));
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
