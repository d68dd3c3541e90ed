//! `ctadsa report RUN_DIR`.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

#[derive(Args)]
pub struct ReportArgs {
    /// A finished run folder (with summary.json).
    run_dir: PathBuf,
}

pub fn run(args: ReportArgs) -> Result<()> {
    let written = ctadsa_core::output::report::write_report(&args.run_dir)?;
    for note in &written.left_out {
        eprintln!("warning: left out of the report (unreadable): {note}");
    }
    println!("report written to {}", written.path.display());
    Ok(())
}
