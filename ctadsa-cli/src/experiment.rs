//! `ctadsa experiment`: runs a matrix of (case × views × prior threshold × method) completions,
//! resumably (a cell with a `cell.json` is skipped), and writes `results.csv`, a Markdown table
//! in the paper's layout (mean ± std over cases) and Fig. 3-style plots.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use ctadsa_core::case::Case;
use ctadsa_core::config::Config;
use ctadsa_core::metrics::SurfaceScores;
use ctadsa_core::plot::{PALETTE, Series, line_plot};
use serde::{Deserialize, Serialize};

use crate::backend::BackendKind;
use crate::complete::{Start, run_completion};

#[derive(Args)]
pub struct ExperimentArgs {
    /// Case folders (each with case.json).
    #[arg(long, num_args = 1.., required = true)]
    cases: Vec<PathBuf>,
    /// The matrix (TOML): views, priors, methods; see configs/experiments/.
    #[arg(long)]
    matrix: PathBuf,
    /// Output folder: one sub-folder per cell, and the tables and plots.
    #[arg(long)]
    out: PathBuf,
    /// Backend of every run.
    #[arg(long, value_enum, default_value = "ndarray")]
    backend: BackendKind,
    /// Cells run at the same time (each run already uses every core for its kernels).
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Overrides for every cell, after the matrix's own (repeatable).
    #[arg(long = "set")]
    overrides: Vec<String>,
}

/// One method (row of the paper's tables): a config file and overrides.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Method {
    name: String,
    /// Config path, relative to the matrix file.
    config: PathBuf,
    #[serde(default)]
    set: Vec<String>,
}

/// The matrix file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Matrix {
    /// View subsets (indices into the case's views).
    views: Vec<Vec<usize>>,
    /// Prior folders under each case's `priors/` (empty: the case's own prior).
    #[serde(default)]
    priors: Vec<String>,
    /// Overrides for every cell.
    #[serde(default)]
    set: Vec<String>,
    methods: Vec<Method>,
}

/// The numbers of one finished cell (non-finite values stored as `null`).
#[derive(Debug, Clone, Serialize, Deserialize)]
struct CellResult {
    case: String,
    method: String,
    views: usize,
    view_list: String,
    prior: String,
    prior_threshold_mm: Option<f64>,
    seconds: f64,
    gaussians: usize,
    metrics: BTreeMap<String, Option<f64>>,
}

struct Cell {
    case_dir: PathBuf,
    case_name: String,
    method: Method,
    views: Vec<usize>,
    prior: Option<String>,
    dir: PathBuf,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

fn put(m: &mut BTreeMap<String, Option<f64>>, prefix: &str, s: Option<&SurfaceScores>) {
    let s = s.copied();
    m.insert(format!("{prefix}cd_mean_mm"), s.and_then(|s| finite(s.cd_mean_mm)));
    m.insert(format!("{prefix}cd_sum_mm"), s.and_then(|s| finite(s.cd_sum_mm)));
    m.insert(format!("{prefix}hd95_mm"), s.and_then(|s| finite(s.hd95_mm)));
    m.insert(format!("{prefix}hd_mm"), s.and_then(|s| finite(s.hd_mm)));
}

/// `d1p50mm` → 1.5.
fn threshold_of(tag: &str) -> Option<f64> {
    tag.strip_prefix('d')?.strip_suffix("mm")?.replace('p', ".").parse().ok()
}

/// The case with another of its priors (and the matching missing-vessel surface).
fn with_prior(case: &Case, tag: &str) -> Result<Case> {
    let mut c = case.clone();
    let prior = format!("priors/{tag}/prior.obj");
    let missing = format!("priors/{tag}/missing.obj");
    for p in [&prior, &missing] {
        if !case.path(p).exists() {
            bail!("case {}: {} does not exist (synthesise the case with this prior threshold)", case.dir.display(), p);
        }
    }
    let threshold = threshold_of(tag);
    c.file.prior = Some(ctadsa_core::case::PriorEntry {
        mesh: prior,
        description: format!("prior {tag}"),
        threshold_mm: threshold,
    });
    if let Some(gt) = c.file.ground_truth.as_mut() {
        gt.missing_mesh = Some(missing);
    }
    Ok(c)
}

fn run_cell(cell: &Cell, matrix_dir: &Path, common: &[String], backend: BackendKind) -> Result<CellResult> {
    let case = Case::load(&cell.case_dir)?;
    let case = match &cell.prior {
        Some(tag) => with_prior(&case, tag)?,
        None => case,
    };
    let view_list = cell.views.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
    let mut overrides = common.to_vec();
    overrides.extend(cell.method.set.iter().cloned());
    overrides.push(format!("run.views=[{view_list}]"));
    let cfg = Config::load(Some(&matrix_dir.join(&cell.method.config)), &overrides)
        .with_context(|| format!("method {}", cell.method.name))?;
    let start = Instant::now();
    let summary = run_completion(&case, cfg, backend, &cell.dir, Start::Overwrite)?.context("interrupted")?;
    let mut metrics = BTreeMap::new();
    let m = summary.metrics.as_ref();
    put(&mut metrics, "", m.map(|m| &m.overall));
    put(&mut metrics, "roi_", m.and_then(|m| m.roi.as_ref()));
    put(&mut metrics, "prior_", m.and_then(|m| m.prior.as_ref()));
    if let Some(c) = &summary.coverage {
        metrics.insert("missing_recall".into(), c.missing_recall.and_then(finite));
        metrics.insert("missing_surface_within_1mm".into(), c.missing_surface_within_1mm.and_then(finite));
        metrics.insert("false_surface".into(), finite(c.false_surface));
    }
    // The untouched prior mesh, scored the same way, for comparison.
    let p = summary.prior_metrics.as_ref();
    put(&mut metrics, "untouched_prior_", p.map(|m| &m.overall));
    let result = CellResult {
        case: cell.case_name.clone(),
        method: cell.method.name.clone(),
        views: cell.views.len(),
        view_list,
        prior: cell.prior.clone().unwrap_or_else(|| "case".into()),
        prior_threshold_mm: case.file.prior.as_ref().and_then(|p| p.threshold_mm),
        seconds: start.elapsed().as_secs_f64(),
        gaussians: summary.gaussians,
        metrics,
    };
    ctadsa_core::error::write_file(&cell.dir.join("cell.json"), serde_json::to_string_pretty(&result)?.as_bytes())?;
    Ok(result)
}

fn mean_std(v: &[f64]) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    Some((m, var.sqrt()))
}

/// Mean ± std of a metric over the results; cells where it is undefined (e.g. no point in the
/// ROI) are counted and shown.
fn cell_text(rs: &[&CellResult], key: &str) -> String {
    let vals: Vec<f64> = rs.iter().filter_map(|r| r.metrics.get(key).copied().flatten()).collect();
    let missing = rs.len() - vals.len();
    let core = match mean_std(&vals) {
        Some((m, s)) => format!("{m:.2} ± {s:.2}"),
        None => "—".into(),
    };
    if missing > 0 { format!("{core} ({missing}× ∞)") } else { core }
}

fn write_tables(out: &Path, results: &[CellResult], matrix: &Matrix) -> Result<()> {
    // CSV, one row per cell.
    let keys: Vec<String> = results.first().map(|r| r.metrics.keys().cloned().collect()).unwrap_or_default();
    let mut csv =
        format!("case,method,views,view_list,prior,prior_threshold_mm,seconds,gaussians,{}\n", keys.join(","));
    for r in results {
        let vals: Vec<String> = keys
            .iter()
            .map(|k| r.metrics.get(k).copied().flatten().map_or("inf".into(), |v| format!("{v:.4}")))
            .collect();
        csv += &format!(
            "{},{},{},\"{}\",{},{},{:.1},{},{}\n",
            r.case,
            r.method,
            r.views,
            r.view_list,
            r.prior,
            r.prior_threshold_mm.map_or(String::new(), |v| format!("{v}")),
            r.seconds,
            r.gaussians,
            vals.join(",")
        );
    }
    ctadsa_core::error::write_file(&out.join("results.csv"), csv.as_bytes())?;

    // Markdown: rows = method (× prior when several), columns = views × (CD_ROI, HD95_ROI, CD, HD95).
    let cases: std::collections::BTreeSet<&str> = results.iter().map(|r| r.case.as_str()).collect();
    let mut md = format!(
        "Mean ± std over {} case(s). CD = sum of the two one-sided mean distances (the reference's \
         convention), HD95 = 95th-percentile Hausdorff, in mm; ROI = the vessels missing from the prior.\n\n",
        cases.len()
    );
    let view_counts: Vec<usize> = {
        let mut v: Vec<usize> = matrix.views.iter().map(Vec::len).collect();
        v.dedup();
        v
    };
    md += "| method | prior |";
    for v in &view_counts {
        md += &format!(" CD_ROI ({v} views) | HD95_ROI ({v} views) | CD ({v} views) | HD95 ({v} views) |");
    }
    md += "\n|---|---|";
    for _ in &view_counts {
        md += "---:|---:|---:|---:|";
    }
    md += "\n";
    let priors: Vec<String> = {
        let mut p: Vec<String> = results.iter().map(|r| r.prior.clone()).collect();
        p.sort();
        p.dedup();
        p
    };
    for m in &matrix.methods {
        for p in &priors {
            let sel: Vec<&CellResult> = results.iter().filter(|r| r.method == m.name && &r.prior == p).collect();
            if sel.is_empty() {
                continue;
            }
            md += &format!("| {} | {} |", m.name, p);
            for v in &view_counts {
                let s: Vec<&CellResult> = sel.iter().copied().filter(|r| r.views == *v).collect();
                for key in ["roi_cd_sum_mm", "roi_hd95_mm", "cd_sum_mm", "hd95_mm"] {
                    md += &format!(" {} |", cell_text(&s, key));
                }
            }
            md += "\n";
        }
    }
    ctadsa_core::error::write_file(&out.join("table.md"), md.as_bytes())?;
    println!("\n{md}");

    // Fig. 3: ROI metrics against the prior threshold, one series per method and view count.
    if priors.len() > 1 {
        for (key, label, file) in
            [("roi_cd_sum_mm", "CD ROI (mm)", "fig3-cd-roi.png"), ("roi_hd95_mm", "HD95 ROI (mm)", "fig3-hd95-roi.png")]
        {
            let mut series = Vec::new();
            for m in &matrix.methods {
                for v in &view_counts {
                    let mut pts: Vec<(f64, f64)> = Vec::new();
                    for p in &priors {
                        let s: Vec<f64> = results
                            .iter()
                            .filter(|r| r.method == m.name && &r.prior == p && r.views == *v)
                            .filter_map(|r| r.metrics.get(key).copied().flatten())
                            .collect();
                        if let (Some(t), Some((mean, _))) = (threshold_of(p), mean_std(&s)) {
                            pts.push((t, mean));
                        }
                    }
                    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                    let rgb = PALETTE[series.len() % PALETTE.len()];
                    series.push(Series { name: format!("{} {}v", m.name, v), points: pts, rgb });
                }
            }
            line_plot(&out.join(file), label, "prior threshold (mm)", label, &series, false)?;
        }
    }
    Ok(())
}

pub fn run(args: ExperimentArgs) -> Result<()> {
    let text =
        std::fs::read_to_string(&args.matrix).with_context(|| format!("cannot read {}", args.matrix.display()))?;
    let matrix: Matrix = toml::from_str(&text).with_context(|| format!("{}: invalid matrix", args.matrix.display()))?;
    if matrix.views.is_empty() || matrix.methods.is_empty() {
        bail!("{}: the matrix needs at least one view subset and one method", args.matrix.display());
    }
    for m in &matrix.methods {
        ctadsa_core::error::check_file_name(&m.name, "method name")
            .map_err(|e| anyhow::anyhow!("{}: {e}", args.matrix.display()))?;
    }
    for p in &matrix.priors {
        ctadsa_core::error::check_file_name(p, "prior folder")
            .map_err(|e| anyhow::anyhow!("{}: {e}", args.matrix.display()))?;
    }
    let matrix_dir = args.matrix.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut common = matrix.set.clone();
    common.extend(args.overrides.iter().cloned());
    // Check every method's config once, before anything runs.
    for m in &matrix.methods {
        Config::load(Some(&matrix_dir.join(&m.config)), &[common.clone(), m.set.clone()].concat())
            .with_context(|| format!("method {}", m.name))?;
    }
    let priors: Vec<Option<String>> =
        if matrix.priors.is_empty() { vec![None] } else { matrix.priors.iter().cloned().map(Some).collect() };
    let mut cells = Vec::new();
    for case_dir in &args.cases {
        let case_name = case_dir.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_else(|| "case".into());
        for prior in &priors {
            for views in &matrix.views {
                for method in &matrix.methods {
                    let tag = views.iter().map(|v| v.to_string()).collect::<Vec<_>>().join("-");
                    let dir = args
                        .out
                        .join("cells")
                        .join(&case_name)
                        .join(prior.as_deref().unwrap_or("case"))
                        .join(format!("views-{tag}"))
                        .join(&method.name);
                    cells.push(Cell {
                        case_dir: case_dir.clone(),
                        case_name: case_name.clone(),
                        method: method.clone(),
                        views: views.clone(),
                        prior: prior.clone(),
                        dir,
                    });
                }
            }
        }
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let results = Mutex::new(Vec::new());
    let todo: Vec<&Cell> = cells
        .iter()
        .filter(|c| match std::fs::read(c.dir.join("cell.json")) {
            Ok(bytes) => match serde_json::from_slice::<CellResult>(&bytes) {
                Ok(r) => {
                    results.lock().expect("no poisoned lock").push(r);
                    false
                }
                Err(_) => true,
            },
            Err(_) => true,
        })
        .collect();
    eprintln!("{} cells: {} done before, {} to run", cells.len(), cells.len() - todo.len(), todo.len());
    let queue = Mutex::new(todo.into_iter().enumerate());
    let total = cells.len();
    let failures = Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..args.jobs.max(1) {
            s.spawn(|| {
                loop {
                    let Some((k, cell)) = queue.lock().expect("no poisoned lock").next() else { break };
                    eprintln!(
                        "cell {}/{}: {} / {} / views {:?} / {}",
                        k + 1,
                        total,
                        cell.case_name,
                        cell.prior.as_deref().unwrap_or("case prior"),
                        cell.views,
                        cell.method.name
                    );
                    match run_cell(cell, &matrix_dir, &common, args.backend) {
                        Ok(r) => results.lock().expect("no poisoned lock").push(r),
                        Err(e) => {
                            failures.lock().expect("no poisoned lock").push(format!("{}: {e:#}", cell.dir.display()))
                        }
                    }
                }
            });
        }
    });
    let mut results = results.into_inner().expect("no poisoned lock");
    results.sort_by(|a, b| (&a.case, &a.prior, a.views, &a.method).cmp(&(&b.case, &b.prior, b.views, &b.method)));
    write_tables(&args.out, &results, &matrix)?;
    let failures = failures.into_inner().expect("no poisoned lock");
    if !failures.is_empty() {
        bail!("{} cell(s) failed (finished cells are kept; rerun to retry):\n{}", failures.len(), failures.join("\n"));
    }
    eprintln!("results in {}", args.out.display());
    Ok(())
}
