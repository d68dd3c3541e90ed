//! `ctadsa ensemble`: average finished runs of one case and write the outputs of their mean.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use ctadsa_core::data::case::Case;
use ctadsa_core::run::completion::Monitor;
use ctadsa_core::run::ensemble::run_ensemble;

use crate::backend::BackendKind;
use crate::complete::print_summary;

#[derive(Args)]
pub struct EnsembleArgs {
    /// Case folder (with case.json) the runs completed.
    #[arg(long)]
    case: PathBuf,
    /// Finished run folders of that case, all of the same views (2 to 16); the first gives the
    /// configuration, Gaussians and renders written.
    #[arg(long, num_args = 2.., required = true)]
    runs: Vec<PathBuf>,
    /// Output folder for the ensemble's outputs (not one of the runs).
    #[arg(long)]
    out: PathBuf,
    /// Replace the outputs of an earlier ensemble in the output folder.
    #[arg(long)]
    overwrite: bool,
    /// Where the models are read and voxelised: ndarray (CPU) or wgpu (GPU).
    #[arg(long, value_enum, default_value = "ndarray")]
    backend: BackendKind,
}

/// Prints what the ensemble reads.
struct Notes;

impl Monitor for Notes {
    fn note(&mut self, line: &str) {
        eprintln!("{line}");
    }
}

pub fn run(args: EnsembleArgs) -> Result<()> {
    let case = Case::load(&args.case)?;
    let device = args.backend.device()?.autodiff();
    let summary = run_ensemble(&case, &args.runs, device, &args.out, args.overwrite, &mut Notes)?;
    print_summary(&summary, &args.out);
    Ok(())
}
