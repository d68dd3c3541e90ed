//! `ctadsa eval`: Chamfer and Hausdorff distances of a predicted vessel surface to a ground truth,
//! overall and (with the prior and missing-vessel surfaces) per region.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ctadsa_core::data::mesh::io::read_mesh;
use ctadsa_core::data::tree::prior::split_by_diameter;
use ctadsa_core::data::tree::swc::read_swc;
use ctadsa_core::error::write_file;
use ctadsa_core::eval::metrics::{RegionScores, SurfaceScores};
use ctadsa_core::eval::score::{EvalOptions, EvalReport, evaluate_files};
use ctadsa_core::eval::topology::topology_of_surfaces;

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
    /// Paper column: area-uniform samples instead of mesh vertices.
    #[arg(long)]
    paper_samples: bool,
    /// The true centreline tree (SWC, world mm, e.g. a case's gt/tree.swc): gives clDice and the
    /// Betti-0 error, and with --prior-diameter the recall of the missing vessels.
    #[arg(long)]
    tree: Option<PathBuf>,
    /// Vessels thinner than this (mm) are the missing ones (the case's prior threshold).
    #[arg(long, requires = "tree")]
    prior_diameter: Option<f64>,
    /// With --tree: voxel (mm) of the grid on which clDice and the Betti-0 error are scored
    /// (both surfaces voxelised, the prediction's skeleton traced by TEASAR).
    #[arg(long, default_value_t = 0.6)]
    topology_voxel_mm: f64,
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

fn table(title: &str, r: &RegionScores) {
    println!("{title}\n");
    println!(
        "| region | CD mean (mm) | CD sum (mm) | HD95 (mm) | HD max (mm) | pred→gt (mm) | gt→pred (mm) | points pred / gt |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    row("overall", &r.overall);
    if let Some(s) = &r.roi {
        row("ROI (missing vessels)", s);
    }
    if let Some(s) = &r.prior {
        row("prior region", s);
    }
}

/// Prints a report as Markdown tables: exact distances, coverage, the paper's convention.
pub fn print_report(r: &EvalReport) {
    table("Exact point-to-surface distances (samples on each surface):", &r.scores);
    let c = &r.coverage;
    let pct = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{:.1} %", 100.0 * v));
    println!(
        "\nfalse surface (> 2 mm from every true vessel): {}; missing surface within 1 mm: {}; missing-vessel recall (centreline within radius + 0.5 mm): {}\n",
        pct(Some(c.false_surface)),
        pct(c.missing_surface_within_1mm),
        pct(c.missing_recall)
    );
    let what = if r.options.paper_samples { "area samples" } else { "mesh vertices" };
    table(&format!("Paper convention (nearest points between {what}):"), &r.paper);
    if let (Some(m), Some(t)) = (r.icp_mean_mm, r.icp_translation_mm) {
        println!(
            "\nICP: mean distance after alignment {m:.3} mm, translation [{:.3}, {:.3}, {:.3}] mm",
            t[0], t[1], t[2]
        );
    }
}

pub fn run(args: EvalArgs) -> Result<()> {
    let options = EvalOptions {
        samples: args.samples,
        seed: args.seed,
        paper_samples: args.paper_samples,
        icp: args.icp,
        min_island_mm2: args.min_island_mm2,
    };
    let split = match (&args.prior, &args.missing) {
        (Some(p), Some(m)) => Some((p.as_path(), m.as_path())),
        _ => None,
    };
    let v = args.topology_voxel_mm;
    // Checked before the distances are computed: a bad flag should not cost the scoring first.
    anyhow::ensure!(v.is_finite() && (0.05..=10.0).contains(&v), "--topology-voxel-mm must be in [0.05, 10], got {v}");
    let tree = match &args.tree {
        Some(path) => Some(read_swc(path)?.tree),
        None => None,
    };
    let missing = match (&tree, args.prior_diameter) {
        (Some(tree), Some(d)) => {
            anyhow::ensure!(d.is_finite() && d >= 0.0, "--prior-diameter must be ≥ 0 mm, got {d}");
            Some(split_by_diameter(tree, d).missing)
        }
        _ => None,
    };
    let report = evaluate_files(&args.pred, &args.gt, split, missing.as_deref(), &options)?;
    print_report(&report);
    let topology = match &tree {
        Some(tree) => {
            let v = args.topology_voxel_mm;
            let t = topology_of_surfaces(&read_mesh(&args.pred)?, &read_mesh(&args.gt)?, &tree.segments(), v)?;
            println!(
                "\ntopology on {v} mm voxels: clDice {:.3} (topology precision {:.3}, sensitivity {:.3}), \
                 {} components against {} (Betti-0 error {})",
                t.cl_dice,
                t.topology_precision,
                t.topology_sensitivity,
                t.components,
                t.true_components,
                t.betti0_error
            );
            Some(t)
        }
        None => None,
    };
    let mut value = serde_json::to_value(&report)?;
    if let (Some(object), Some(t)) = (value.as_object_mut(), topology) {
        object.insert("topology".into(), serde_json::to_value(t)?);
    }
    let json = serde_json::to_string_pretty(&value)?;
    match &args.json {
        Some(path) => write_file(path, json.as_bytes())?,
        None => println!("\n{json}"),
    }
    Ok(())
}
