//! `ctadsa bench train-suite`: `ctadsa_core::bench::bench_train` for the quick config and the
//! paper schedule, row after row in this process (the peak memory reset before each row),
//! gathered into one table with the machine.

use std::path::Path;

use anyhow::Result;
use ctadsa_core::bench::{TrainBenchReport, TrainBenchSettings, bench_train, peak_rss_mib, reset_peak_rss};
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::synth::{SynthConfig, synthesize};

use crate::backend::BackendKind;

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

/// One row: `steps` timed steps of the built-in paper-method baseline (or quick configuration)
/// with `sets` on `case`.
fn bench_row(case: &Path, paper: bool, sets: &[&str], steps: usize, backend: BackendKind) -> Result<TrainBenchReport> {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let cfg = if paper { Config::paper_method(&sets)? } else { Config::quick(&sets)? };
    let case = Case::load(case)?;
    let device = backend.device()?.autodiff();
    Ok(bench_train(&case, cfg, device, TrainBenchSettings { steps, device_timed_steps: 0 })?)
}

pub fn train_suite(steps: usize, threads: usize, backend: BackendKind) -> Result<()> {
    // Removed when dropped, on an error too; a fresh name per run.
    let work = tempfile::Builder::new().prefix("ctadsa-bench-suite-").tempdir()?;
    let dir = work.path();
    let (demo, wide) = (dir.join("demo-case"), dir.join("case-512"));
    eprintln!("synthesising the demo case and a 512² variant into {}", dir.display());
    let demo_cfg = SynthConfig::demo();
    synthesize(&demo_cfg, &demo, &mut |_| {})?;
    let wide_cfg = SynthConfig { name: "demo-procedural-512".into(), detector_px: Some(512), binning: 1, ..demo_cfg };
    synthesize(&wide_cfg, &wide, &mut |_| {})?;
    let rows: [(&str, &Path, bool, Vec<&str>); 4] = [
        ("quick (demo case: 3 views of 128², all per step, 33k Gaussians, 2^14)", &demo, false, vec![]),
        ("paper schedule: 1 view of 512² per step, 60k Gaussians, 2^19", &wide, true, vec![]),
        ("paper schedule, the reference's table 2^20", &wide, true, vec!["field.encoding.log2_table=20"]),
        // A paper run densifies without a cap: a BraVa tree grows to ≈ 100k Gaussians by
        // iteration 9,000 and keeps them to the end.
        ("paper schedule, grown to 100k Gaussians, 2^19", &wide, true, vec!["init.n1=50000", "init.n2=50000"]),
    ];
    let mut table = format!(
        "{backend:?}, {} CPU threads on {}; {steps} timed steps per row after 2 warm-up steps (ms; densify: one call)\n\n\
         | configuration | field | render | losses | backward | Adam | **total per step** | densify | init | peak RSS (MiB) |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        threads,
        cpu_model()
    );
    let per_row_memory = reset_peak_rss();
    for (name, case, paper, sets) in rows {
        eprintln!("timing: {name}");
        reset_peak_rss();
        let r = bench_row(case, paper, &sets, steps, backend)?;
        let s = r.stages;
        let cells: Vec<String> =
            [s.field, s.render, s.losses, s.backward, s.optimizer, r.per_step_s, r.densify_s, r.init_s]
                .iter()
                .map(|v| format!("{:.1}", v * 1e3))
                .collect();
        let rss = peak_rss_mib().filter(|_| per_row_memory).map_or("–".into(), |m| format!("{m:.0}"));
        table += &format!("| {name} | {} | {rss} |\n", cells.join(" | "));
    }
    println!("{table}");
    Ok(())
}
