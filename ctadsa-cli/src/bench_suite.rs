//! `ctadsa bench train-suite`: `bench train` for the quick config and the paper schedule, each in
//! a child process, gathered into one table with the machine.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use ctadsa_core::data::synth::{SynthConfig, synthesize};

use crate::backend::BackendKind;

/// The paper configuration, built in so that the suite runs from any folder.
const PAPER_TOML: &str = include_str!("../../configs/paper.toml");

/// The figures one `bench train` run printed: stage → ms, and the peak memory (MiB).
fn parse_bench(stdout: &str) -> (BTreeMap<String, f64>, Option<f64>) {
    let mut stages = BTreeMap::new();
    let mut rss = None;
    for line in stdout.lines() {
        if let Some(rest) = line.strip_prefix("peak resident memory: ") {
            rss = rest.trim_end_matches(" MiB").trim().parse().ok();
        }
        let cells: Vec<&str> = line.split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
        if let [name, value] = cells.as_slice()
            && let Ok(v) = value.trim_matches('*').parse::<f64>()
        {
            let key = name.trim_matches('*').split(" (").next().unwrap_or(name).to_string();
            stages.insert(key, v);
        }
    }
    (stages, rss)
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

/// How one row runs: timed steps, rayon threads, backend.
#[derive(Clone, Copy)]
struct RowRun {
    steps: usize,
    threads: usize,
    backend: BackendKind,
}

fn bench_row(case: &Path, config: Option<&Path>, sets: &[&str], run: RowRun) -> Result<String> {
    let exe = std::env::current_exe().context("cannot find the ctadsa binary")?;
    let mut cmd = Command::new(exe);
    // The flag's value as clap spells it (every variant has one).
    let backend = run.backend.to_possible_value().map(|v| v.get_name().to_owned()).unwrap_or_default();
    cmd.args(["bench", "--threads", &run.threads.to_string(), "train", "--steps", &run.steps.to_string()]);
    cmd.args(["--backend", &backend]);
    cmd.arg("--case").arg(case);
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    for s in sets {
        cmd.args(["--set", s]);
    }
    let out = cmd.output().context("cannot run `ctadsa bench train`")?;
    if !out.status.success() {
        bail!("bench train failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

pub fn train_suite(steps: usize, threads: usize, backend: BackendKind) -> Result<()> {
    let dir = std::env::temp_dir().join(format!("ctadsa-bench-suite-{}", std::process::id()));
    let (demo, wide) = (dir.join("demo-case"), dir.join("case-512"));
    eprintln!("synthesising the demo case and a 512² variant into {}", dir.display());
    let demo_cfg = crate::complete::demo_case_config();
    synthesize(&demo_cfg, &demo, &mut |_| {})?;
    let wide_cfg = SynthConfig { name: "demo-procedural-512".into(), detector_px: Some(512), binning: 1, ..demo_cfg };
    synthesize(&wide_cfg, &wide, &mut |_| {})?;
    let paper = dir.join("paper.toml");
    std::fs::write(&paper, PAPER_TOML).with_context(|| format!("cannot write {}", paper.display()))?;
    let rows: [(&str, &Path, Option<&Path>, Vec<&str>); 4] = [
        ("quick (demo case: 3 views of 128², all per step, 33k Gaussians, 2^14)", &demo, None, vec![]),
        ("paper schedule: 1 view of 512² per step, 60k Gaussians, 2^19", &wide, Some(&paper), vec![]),
        ("paper schedule, the reference's table 2^20", &wide, Some(&paper), vec!["field.encoding.log2_table=20"]),
        // A paper run densifies without a cap: a BraVa tree grows to ≈ 100k Gaussians by
        // iteration 9,000 and keeps them to the end.
        ("paper schedule, grown to 100k Gaussians, 2^19", &wide, Some(&paper), vec!["init.n1=50000", "init.n2=50000"]),
    ];
    let columns = ["field", "render", "losses", "backward", "optimiser", "total per step", "densify", "initialisation"];
    let mut table = format!(
        "{backend:?}, {} CPU threads on {}; {steps} timed steps per row after 2 warm-up steps (ms; densify: one call)\n\n\
         | configuration | field | render | losses | backward | Adam | **total per step** | densify | init | peak RSS (MiB) |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        threads,
        cpu_model()
    );
    for (name, case, config, sets) in rows {
        eprintln!("timing: {name}");
        let (stages, rss) = parse_bench(&bench_row(case, config, &sets, RowRun { steps, threads, backend })?);
        let cells: Vec<String> =
            columns.iter().map(|c| stages.get(*c).map_or("–".into(), |v| format!("{v:.1}"))).collect();
        table += &format!("| {name} | {} | {} |\n", cells.join(" | "), rss.map_or("–".into(), |m| format!("{m:.0}")));
    }
    println!("{table}");
    std::fs::remove_dir_all(&dir).ok();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_train_output_is_parsed_into_stages_and_memory() {
        let out = "| stage | ms per step |\n|---|---:|\n| field (hash grid + MLP) | 12.5 |\n\
                   | **total per step** | **82.5** |\n| densify (one call: 0 cloned, 33 split, 0 pruned) | 20.7 |\n\
                   | initialisation (once) | 803 |\n\npeak resident memory: 89 MiB\n";
        let (stages, rss) = parse_bench(out);
        assert_eq!(stages.get("field"), Some(&12.5));
        assert_eq!(stages.get("total per step"), Some(&82.5));
        assert_eq!(stages.get("densify"), Some(&20.7));
        assert_eq!(stages.get("initialisation"), Some(&803.0));
        assert_eq!(rss, Some(89.0));
    }
}
