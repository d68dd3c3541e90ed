//! An experiment matrix run as SLURM job arrays (`configs/slurm/submit.sh`: one array task per
//! run cell, then one per ensemble cell, then a collect job) gives the same table as the same
//! matrix run on this machine.
//! Needs a SLURM cluster that answers `sinfo` (CI starts a single-node one with
//! `.ci/slurm-up`); without one the test prints why and passes, unless `CTADSA_REQUIRE_SLURM=1`.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

mod common;
use common::{BIN, small_case_from, tmp};

fn slurm_available() -> Result<(), String> {
    match Command::new("sinfo").args(["-h", "-o", "%T"]).output() {
        Ok(o) if o.status.success() && !o.stdout.is_empty() => Ok(()),
        Ok(o) => Err(format!("`sinfo` failed: {}", String::from_utf8_lossy(&o.stderr).trim())),
        Err(e) => Err(format!("no `sinfo` on the PATH ({e})")),
    }
}

/// The experiment arguments shared by both runs: two cases, two methods and their ensemble,
/// 2 views, a few iterations.
fn experiment_args(cases: &[&Path], matrix: &Path, out: &Path) -> Vec<String> {
    let mut a: Vec<String> = vec!["--cases".into()];
    a.extend(cases.iter().map(|c| c.to_str().unwrap().to_string()));
    a.extend(["--matrix".into(), matrix.to_str().unwrap().into(), "--out".into(), out.to_str().unwrap().into()]);
    for s in ["run.iterations=12", "init.n1=300", "init.n2=200", "densify.enabled=false", "output.metric_samples=1500"]
    {
        a.extend(["--set".into(), s.into()]);
    }
    a
}

/// results.csv without the wall-clock column.
/// `table.md` with every wall-clock cell ("0.1 min") blanked: the two runs' timings differ,
/// and on a loaded machine they round to different tenths of a minute.
fn markdown_without_wall_clock(out: &Path) -> String {
    let text = std::fs::read_to_string(out.join("table.md")).expect("table.md");
    text.lines()
        .map(|l| {
            l.split(" | ")
                .map(|cell| {
                    let minutes = cell.strip_suffix(" min").is_some_and(|n| n.parse::<f64>().is_ok());
                    if minutes { "…" } else { cell }
                })
                .collect::<Vec<_>>()
                .join(" | ")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn table_without_seconds(out: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(out.join("results.csv")).expect("results.csv");
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|h| *h == "seconds").expect("a seconds column");
    // The view list is quoted and holds commas.
    text.lines()
        .map(|l| {
            let unquoted = match l.split('"').collect::<Vec<_>>().as_slice() {
                [head, list, tail] => format!("{head}{}{tail}", list.replace(',', ";")),
                _ => l.to_string(),
            };
            let mut fields: Vec<&str> = unquoted.split(',').collect();
            fields.remove(col);
            fields.join(",")
        })
        .collect()
}

fn wait_for_jobs(ids: &[&str], limit: Duration) {
    let started = Instant::now();
    loop {
        let q = Command::new("squeue").args(["-h", "-o", "%i %T", "-j", &ids.join(",")]).output().expect("squeue");
        let pending = String::from_utf8_lossy(&q.stdout).to_string();
        if pending.trim().is_empty() {
            return;
        }
        assert!(started.elapsed() < limit, "SLURM jobs still queued after {limit:?}:\n{pending}");
        std::thread::sleep(Duration::from_secs(2));
    }
}

#[test]
fn a_slurm_job_array_gives_the_same_table_as_a_local_run() {
    if let Err(why) = slurm_available() {
        if std::env::var("CTADSA_REQUIRE_SLURM").is_ok_and(|v| v == "1") {
            panic!("CTADSA_REQUIRE_SLURM=1 but {why}");
        }
        eprintln!("SKIPPED: SLURM job-array test not run: {why}");
        return;
    }
    let root = tmp("slurm");
    let _ = std::fs::remove_dir_all(&root);
    let (case_a, case_b) = (root.join("case-a"), root.join("case-b"));
    small_case_from(&case_a, 1);
    small_case_from(&case_b, 2);
    let quick = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/quick.toml");
    let matrix = root.join("matrix.toml");
    std::fs::write(
        &matrix,
        format!(
            "views = [[0, 1]]\n[[methods]]\nname = \"full\"\nconfig = \"{quick}\"\n\n\
             [[methods]]\nname = \"prior-only\"\nconfig = \"{quick}\"\nset = [\"init.n2 = 0\"]\n\n\
             [[ensembles]]\nname = \"both\"\nmethods = [\"full\", \"prior-only\"]\n"
        ),
    )
    .unwrap();
    let cases = [case_a.as_path(), case_b.as_path()];

    // On this machine, one cell after the other.
    let local = root.join("local");
    let run = Command::new(BIN).arg("experiment").args(experiment_args(&cases, &matrix, &local)).output().unwrap();
    assert!(run.status.success(), "local run: {}", String::from_utf8_lossy(&run.stderr));

    // The list names 6 cells, the ensembles last; the arrays run them, the collect job gathers
    // them.
    let on_slurm = root.join("slurm");
    let args = experiment_args(&cases, &matrix, &on_slurm);
    let list = Command::new(BIN).arg("experiment").args(&args).arg("--list").output().unwrap();
    let list = String::from_utf8_lossy(&list.stdout).to_string();
    let kinds: Vec<&str> = list.lines().map(|l| l.split('\t').nth(2).unwrap_or("")).collect();
    assert_eq!(
        kinds,
        ["run", "run", "run", "run", "ensemble", "ensemble"],
        "2 cases × (2 methods + 1 ensemble):\n{list}"
    );
    assert!(list.contains("\ttodo (after cells 2, 3)\tensemble\t"), "what an ensemble waits for:\n{list}");
    let submit = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/slurm/submit.sh");
    let sub = Command::new("bash").arg(submit).args(&args).env("CTADSA", BIN).output().unwrap();
    assert!(sub.status.success(), "submit.sh: {}", String::from_utf8_lossy(&sub.stderr));
    let ids = String::from_utf8_lossy(&sub.stdout).to_string();
    let ids: Vec<&str> = ids.split_whitespace().collect();
    assert_eq!(ids.len(), 3, "submit.sh prints the two arrays' and the collect job's ids: {ids:?}");
    wait_for_jobs(&ids, Duration::from_secs(600));

    for i in 0..6 {
        let log = on_slurm.join(format!("logs/cell-{i}.log"));
        assert!(log.exists(), "array task {i} wrote its log {}", log.display());
    }
    let collect_log = std::fs::read_to_string(on_slurm.join("logs/collect.log")).unwrap_or_default();
    assert!(on_slurm.join("results.csv").exists(), "the collect job wrote results.csv:\n{collect_log}");
    let (a, b) = (table_without_seconds(&local), table_without_seconds(&on_slurm));
    assert_eq!(a.len(), 7, "header + 6 cells: {a:#?}");
    assert_eq!(a.iter().filter(|row| row.contains(",both,")).count(), 2, "an ensemble row per case: {a:#?}");
    assert_eq!(a, b, "the job array's table equals the local run's");
    let (local_md, slurm_md) = (markdown_without_wall_clock(&local), markdown_without_wall_clock(&on_slurm));
    assert!(local_md.contains('…'), "table.md has a wall-clock column:\n{local_md}");
    assert_eq!(local_md, slurm_md, "the job array's table.md equals the local run's but for the wall-clock");

    // Resubmitting finds every cell finished and changes nothing.
    let again = Command::new(BIN).arg("experiment").args(&args).arg("--cell").arg("0").output().unwrap();
    assert!(again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("already finished"));
    std::fs::remove_dir_all(&root).ok();
}
