//! `ctadsa diagnose`: where a run lost the missing vessels of its synthetic case.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use ctadsa_core::data::case::Case;
use ctadsa_core::eval::diagnose::diagnose_run;

#[derive(Args)]
pub struct DiagnoseArgs {
    /// The synthetic case (with gt/tree.swc).
    #[arg(long)]
    case: PathBuf,
    /// The finished run folder of `ctadsa complete` on that case.
    #[arg(long)]
    run: PathBuf,
    /// Write the breakdown as JSON here too.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn run(args: DiagnoseArgs) -> Result<()> {
    let case = Case::load(&args.case)?;
    let d = diagnose_run(&case, &args.run)?;
    let b = &d.missing;
    println!("missing centreline: {:.0} mm", b.length_mm);
    println!("| class | share of the missing length |\n|---|---:|");
    for (name, v) in [
        ("found (surface within radius + 0.5 mm)", b.found),
        ("not in every view's vessel mask", b.not_in_masks),
        ("behind the prior's dilated projection in some view", b.behind_prior),
        ("in every residual, but no N2 seed within 1.5 mm", b.not_seeded),
        ("seeded, signal explained at a wrong depth in every view", b.misplaced),
        ("seeded, density below the iso-level", b.faded),
    ] {
        println!("| {name} | {:.1} % |", 100.0 * v);
    }
    if let Some(ns) = &d.new_surface {
        let missing = ns.missing_area_mm2.map_or(String::new(), |a| format!(" (the true missing vessels: {a:.0} mm²)"));
        println!("\nnew surface (the completed surface off the prior): {:.0} mm²{missing}", ns.area_mm2);
        println!(
            "| distance to the prior | share of the new area | mean distance to the truth | farther than 2 mm from it |"
        );
        println!("|---|---:|---:|---:|");
        for band in &ns.bands {
            let range = band.to_mm.map_or(format!("≥ {} mm", band.from_mm), |t| format!("{}–{t} mm", band.from_mm));
            println!(
                "| {range} | {:.1} % | {:.2} mm | {:.1} % |",
                100.0 * band.share,
                band.mean_truth_mm,
                100.0 * band.false_share
            );
        }
    }
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&d)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
