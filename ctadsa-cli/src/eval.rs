//! `ctadsa eval`: Chamfer and Hausdorff distances of a predicted vessel surface to a ground truth,
//! overall and (with the prior and missing-vessel surfaces) per region.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use ctadsa_core::eval::{EvalOptions, EvalReport, evaluate_files};
use ctadsa_core::metrics::SurfaceScores;

#[derive(Args)]
pub struct EvalArgs {
    /// Predicted surface (OBJ, PLY or STL; world mm).
    #[arg(long)]
    pred: PathBuf,
    /// Ground-truth complete surface.
    #[arg(long)]
    gt: PathBuf,
    /// Prior surface (what the CTA showed); with --missing gives ROI and prior-region scores.
    #[arg(long, requires = "missing")]
    prior: Option<PathBuf>,
    /// Surface of the vessels missing from the prior.
    #[arg(long, requires = "prior")]
    missing: Option<PathBuf>,
    /// Area-uniform samples per surface.
    #[arg(long, default_value_t = 20_000)]
    samples: usize,
    /// Sampling seed.
    #[arg(long, default_value_t = 1234)]
    seed: u64,
    /// Use mesh vertices instead of area-uniform samples.
    #[arg(long)]
    vertices: bool,
    /// Rigidly align the prediction to the ground truth by ICP first (reference parity).
    #[arg(long)]
    icp: bool,
    /// Drop connected components of the prediction with less surface than this (mm²) first.
    #[arg(long, default_value_t = 0.0)]
    min_island_mm2: f64,
    /// Write the report as JSON here (default: print it after the table).
    #[arg(long)]
    json: Option<PathBuf>,
}

fn row(region: &str, s: &SurfaceScores) {
    println!(
        "| {region} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {} / {} |",
        s.cd_mean_mm, s.cd_sum_mm, s.hd95_mm, s.hd_mm, s.pred_to_gt_mm, s.gt_to_pred_mm, s.pred_points, s.gt_points
    );
}

/// Prints a report as a Markdown table.
pub fn print_report(r: &EvalReport) {
    println!(
        "| region | CD mean (mm) | CD sum (mm) | HD95 (mm) | HD max (mm) | pred→gt (mm) | gt→pred (mm) | points pred / gt |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    row("overall", &r.scores.overall);
    if let Some(s) = &r.scores.roi {
        row("ROI (missing vessels)", s);
    }
    if let Some(s) = &r.scores.prior {
        row("prior region", s);
    }
    if let (Some(m), Some(t)) = (r.icp_mean_mm, r.icp_translation_mm) {
        println!(
            "\nICP: mean distance after alignment {m:.3} mm, translation [{:.3}, {:.3}, {:.3}] mm",
            t[0], t[1], t[2]
        );
    }
}

pub fn run(args: EvalArgs) -> Result<()> {
    anyhow::ensure!(args.samples >= 1 || args.vertices, "--samples must be ≥ 1");
    let options = EvalOptions {
        samples: args.samples,
        seed: args.seed,
        vertices: args.vertices,
        icp: args.icp,
        min_island_mm2: args.min_island_mm2,
    };
    let split = match (&args.prior, &args.missing) {
        (Some(p), Some(m)) => Some((p.as_path(), m.as_path())),
        _ => None,
    };
    let report = evaluate_files(&args.pred, &args.gt, split, &options)?;
    print_report(&report);
    let json = serde_json::to_string_pretty(&report)?;
    match &args.json {
        Some(path) => std::fs::write(path, json).with_context(|| format!("cannot write {}", path.display()))?,
        None => println!("\n{json}"),
    }
    Ok(())
}
