//! `ctadsa diagnose`: where a run lost the missing vessels of its synthetic case, or (with
//! `--seeds`) where a configuration's image seeds fall before any training.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::error::write_file;
use ctadsa_core::eval::calibre::CalibreBand;
use ctadsa_core::eval::diagnose::{ClassifiedPoint, diagnose_run, diagnose_seeds};

#[derive(Args)]
pub struct DiagnoseArgs {
    /// The synthetic case (with gt/tree.swc).
    #[arg(long)]
    case: PathBuf,
    /// The finished run folder of `ctadsa complete` on that case.
    #[arg(long, required_unless_present = "seeds")]
    run: Option<PathBuf>,
    /// Only the image seeds of a configuration (`--config`, `--set`; those of every model it
    /// trains): which share of the missing centreline gets one, and what the seeds hit. Seconds,
    /// no training.
    #[arg(long, conflicts_with = "run")]
    seeds: bool,
    /// The configuration of `--seeds` (default: the built-in one).
    #[arg(long, requires = "seeds")]
    config: Option<PathBuf>,
    /// Override a config value of `--seeds`: --set section.key=value (repeatable).
    #[arg(long = "set", requires = "seeds")]
    overrides: Vec<String>,
    /// Write the breakdown as JSON here too.
    #[arg(long)]
    json: Option<PathBuf>,
    /// With `--run`: write every classified point of the missing centreline here as CSV
    /// (position and true radius in mm, the length it stands for, its class, the distances to
    /// the nearest image seed and to the completed surface, the density over the iso-level).
    #[arg(long, requires = "run")]
    points: Option<PathBuf>,
}

pub fn run(args: DiagnoseArgs) -> Result<()> {
    let case = Case::load(&args.case)?;
    let Some(run_dir) = &args.run else { return seeds(&case, &args) };
    let d = diagnose_run(&case, run_dir)?;
    let b = &d.missing;
    println!("missing centreline: {:.0} mm", b.length_mm);
    print_shares(
        "class",
        "the missing length",
        &[
            ("found (surface within radius + 0.5 mm)", b.found),
            ("not in every view's vessel mask", b.not_in_masks),
            ("… of which an N2 seed lies within 1.5 mm", b.not_in_masks_seeded),
            ("behind the prior's dilated projection in some view", b.behind_prior),
            ("… of which an N2 seed lies within 1.5 mm", b.behind_prior_seeded),
            ("in every residual, but no N2 seed within 1.5 mm", b.not_seeded),
            ("seeded, signal explained at a wrong depth in every view", b.misplaced),
            ("seeded, density below the iso-level", b.faded),
        ],
    );
    println!("never seeded (not found, no N2 seed within 1.5 mm): {:.1} %", 100.0 * b.never_seeded());
    print_calibre(&d.calibre);
    if let Some(u) = &d.untraced {
        println!("\nfound by the surface, not by the centreline: {:.1} %", 100.0 * u.total());
        let near = ctadsa_core::eval::untraced::NEAR_MM;
        print_shares(
            "the nearest centreline point",
            "the missing length",
            &[
                (&format!("a prior vessel's, within {near} mm (inside its path's cover)"), u.beside_prior),
                (&format!("a new branch's, within {near} mm (the branch off the vessel's axis)"), u.beside_new),
                (&format!("none within {near} mm"), u.none_near),
            ],
        );
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
    if let Some(c) = &d.new_centreline {
        println!("\nnew centreline (centreline.swc, type 4): {:.0} mm", c.length_mm);
        print_shares(
            "where it lies",
            "the new length",
            &[
                ("on a true vessel (within its radius + 0.5 mm)", c.on_vessel),
                ("a ghost within 2 mm of a true vessel (in every view's vessel mask)", c.ghost_near),
                ("a ghost farther from every true vessel (in every view's vessel mask)", c.ghost_far),
                ("off some view's vessel mask", c.off_views),
            ],
        );
    }
    if let Some(path) = &args.points {
        write_points(path, &d.points)?;
    }
    write_json(args.json.as_deref(), &d)
}

/// The missing centreline by true diameter.
fn print_calibre(bands: &[CalibreBand]) {
    if bands.is_empty() {
        return;
    }
    println!("\nby true diameter (found: within radius + 0.5 mm, as the recalls)");
    println!("| diameter | share of the missing length | found by the surface | found by the centreline |");
    println!("|---|---:|---:|---:|");
    let percent = |x: f64| format!("{:.1} %", 100.0 * x);
    for b in bands {
        let range = b.to_mm.map_or(format!("≥ {} mm", b.from_mm), |t| format!("{}–{t} mm", b.from_mm));
        let traced = b.centreline_recall.map_or("no centreline.swc".to_string(), percent);
        println!("| {range} | {} | {} | {traced} |", percent(b.share), percent(b.surface_recall));
    }
}

fn write_points(path: &std::path::Path, points: &[ClassifiedPoint]) -> Result<()> {
    let mut csv =
        String::from("x_mm,y_mm,z_mm,radius_mm,length_mm,class,to_seed_mm,to_surface_mm,density_over_level\n");
    for p in points {
        let [x, y, z] = p.position_mm;
        csv += &format!(
            "{x:.3},{y:.3},{z:.3},{:.3},{:.4},{},{:.3},{:.3},{:.4}\n",
            p.radius_mm,
            p.length_mm,
            p.class.name(),
            p.to_seed_mm,
            p.to_surface_mm,
            p.density_over_level
        );
    }
    Ok(write_file(path, csv.as_bytes())?)
}

fn seeds(case: &Case, args: &DiagnoseArgs) -> Result<()> {
    let cfg = Config::load(args.config.as_deref(), &args.overrides)?;
    let c = diagnose_seeds(case, &cfg)?;
    println!("missing centreline: {:.0} mm; {} image seeds", c.length_mm, c.seeds);
    print_shares(
        "class",
        "the missing length",
        &[
            ("an N2 seed within 1.5 mm", c.seeded),
            ("not in every view's vessel mask", c.not_in_masks),
            ("behind the prior's dilated projection in some view", c.behind_prior),
            ("in every residual, but no N2 seed within 1.5 mm", c.not_seeded),
        ],
    );
    println!(
        "seeds within 1.5 mm of the missing centreline: {:.1} % (median {:.2} mm from it); farther than 2 mm from every true vessel: {:.1} %",
        100.0 * c.on_missing,
        c.on_missing_offset_mm,
        100.0 * c.ghosts
    );
    write_json(args.json.as_deref(), &c)
}

/// A Markdown table of shares (fractions, printed in %) of `of`.
fn print_shares(what: &str, of: &str, rows: &[(&str, f64)]) {
    println!("| {what} | share of {of} |\n|---|---:|");
    for (name, v) in rows {
        println!("| {name} | {:.1} % |", 100.0 * v);
    }
}

fn write_json(path: Option<&std::path::Path>, value: &impl serde::Serialize) -> Result<()> {
    if let Some(path) = path {
        write_file(path, serde_json::to_string_pretty(value)?.as_bytes())?;
    }
    Ok(())
}
