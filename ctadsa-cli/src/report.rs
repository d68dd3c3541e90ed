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
    let path = ctadsa_core::output::report::write_report(&args.run_dir)?;
    println!("report written to {}", path.display());
    Ok(())
}
