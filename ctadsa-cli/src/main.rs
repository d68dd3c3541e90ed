//! `ctadsa`: complete a patient's 3-D cerebral vessel tree from a CTA prior and DSA views.

mod allocator;
mod backend;
mod bench;
mod bench_suite;
mod clinical;
mod complete;
mod diagnose;
mod ensemble;
mod eval;
mod experiment;
mod progress;
mod report;
mod synth;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// ctadsa — 3-D cerebrovascular shape completion from biplane angiography and a CTA prior.
#[derive(Parser)]
#[command(name = "ctadsa", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
#[allow(clippy::large_enum_variant)] // parsed once per process
enum Command {
    /// Synthesise a case folder (views, prior, ground truth) from a vessel tree, a label volume,
    /// or the built-in procedural tree.
    Synth(synth::SynthArgs),
    /// Complete the vessels of a case: optimise Gaussians against its DSA views, starting from
    /// its prior; write the completed mesh, density volume, renders and metrics.
    Complete(complete::CompleteArgs),
    /// Synthesise the built-in phantom case and complete it with the quick CPU configuration.
    Demo(complete::DemoArgs),
    /// Average finished runs of one case (other seeds, budgets or configurations) and write the
    /// outputs of their mean density: mesh, centreline, metrics, report.
    Ensemble(ensemble::EnsembleArgs),
    /// Chamfer and Hausdorff distances (mm) of a predicted surface to a ground truth, overall and
    /// in the missing-vessel region (ROI) and the prior region.
    Eval(eval::EvalArgs),
    /// Where a run on a synthetic case lost the missing vessels: found, not in the vessel masks,
    /// behind the prior, not seeded, misplaced in depth, or faded below the iso-level.
    Diagnose(diagnose::DiagnoseArgs),
    /// Run a matrix of cases × views × prior thresholds × methods (resumable) and tabulate it.
    Experiment(experiment::ExperimentArgs),
    /// Benchmarks (renderer, projector) with a table of timings and throughput.
    Bench(bench::BenchArgs),
    /// Make a case from DSA runs (DICOM XA): subtraction, frame choice, MIP, C-arm geometry from
    /// the positioner tags, and a prior (mesh or CTA label volume).
    ImportDsa(clinical::ImportDsaArgs),
    /// Make a prior mesh from a CTA label volume (NIfTI): chosen labels, small islands removed,
    /// optionally cut to what a case's views see.
    Prior(clinical::PriorArgs),
    /// Write a case's views as simulated DSA runs (multi-frame XA DICOM: mask + contrast bolus),
    /// to try the DICOM path without patient data.
    ExportDicom(clinical::ExportDicomArgs),
    /// Write RUN_DIR/report.html: one self-contained page with the inputs, renders against
    /// targets, the completed mesh, metrics, poses and the configuration.
    Report(report::ReportArgs),
}

fn main() -> std::process::ExitCode {
    allocator::keep_freed_memory();
    backend::prefer_cpu_default_device();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("Error: {e:?}");
            // A backend this machine cannot run: 2, as for other usage errors (clap's).
            let unusable = e.chain().any(|c| c.is::<backend::BackendUnavailable>());
            std::process::ExitCode::from(if unusable { 2 } else { 1 })
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Synth(args) => synth::run(args),
        Command::Complete(args) => complete::run(args),
        Command::Demo(args) => complete::demo(args),
        Command::Ensemble(args) => ensemble::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Diagnose(args) => diagnose::run(args),
        Command::Experiment(args) => experiment::run(args),
        Command::Bench(args) => bench::run(args),
        Command::ImportDsa(args) => clinical::import_dsa(args),
        Command::Prior(args) => clinical::prior(args),
        Command::ExportDicom(args) => clinical::export_dicom(args),
        Command::Report(args) => report::run(args),
    }
}
