//! `ctadsa complete` and `ctadsa demo`: run the shape completion on a case folder.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Result, bail};
use clap::Args;
use ctadsa_core::config::Config;
use ctadsa_core::data::case::Case;
use ctadsa_core::data::synth::{SynthConfig, synthesize_replacing};
use ctadsa_core::data::vessel_evidence::Reading;
use ctadsa_core::method::train::{StepLog, Trainer};
use ctadsa_core::output::export::RunSummary;
use ctadsa_core::run::completion::{self, Monitor, Outcome, Start};
use indicatif::ProgressBar;

use crate::backend::BackendKind;
use crate::progress::bar;

#[derive(Args)]
pub struct CompleteArgs {
    /// Case folder (with case.json).
    #[arg(long)]
    case: PathBuf,
    /// TOML configuration (default: built-in defaults = the paper's values).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Where tensors live: ndarray (CPU) or wgpu (GPU).
    #[arg(long, value_enum, default_value = "ndarray")]
    backend: BackendKind,
    /// Override a config value: --set section.key=value (repeatable).
    #[arg(long = "set")]
    overrides: Vec<String>,
    /// Output folder (default: `runs/<case name>`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Resume from the latest checkpoint in the output folder (or the given checkpoint).
    #[arg(long, num_args = 0..=1, default_missing_value = "latest")]
    resume: Option<String>,
    /// Start afresh in an output folder that holds a run (its checkpoints and summary go).
    #[arg(long, conflicts_with = "resume")]
    overwrite: bool,
}

/// Installs a handler for Ctrl-C (SIGINT), SIGTERM (what `timeout`, SLURM and `docker stop`
/// send) and SIGHUP. During training it raises a flag: the loop saves a checkpoint and stops,
/// and the command exits non-zero. In every other phase (initialisation, outputs, skeleton,
/// report), and on a second signal, the process exits at once with code 130: there is nothing
/// to save there, and every file is written to a temporary name and renamed, so none is left
/// half-written.
fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    // A second handler cannot be installed (e.g. in tests); the run then simply has none.
    let _ = ctrlc::set_handler(move || {
        if ctadsa_core::run::completion::training_in_progress() && !f.swap(true, Ordering::SeqCst) {
            return;
        }
        // Not eprintln!: it panics when stderr is closed (a pipe whose reader is gone), and the
        // process would then not stop.
        let _ = writeln!(std::io::stderr(), "interrupted: stopping now (nothing of this phase to save)");
        std::process::exit(130);
    });
    flag
}

/// What the terminal shows of a run: a progress bar, or a log line every 10 % without a
/// terminal; Ctrl-C / SIGTERM ask the run to stop.
pub struct Terminal {
    pb: ProgressBar,
    stop: Arc<AtomicBool>,
    began: Instant,
    first: usize,
    iterations: usize,
}

impl Terminal {
    /// A terminal monitor with the interrupt handler installed.
    pub fn new() -> Self {
        Self { pb: ProgressBar::hidden(), stop: interrupt_flag(), began: Instant::now(), first: 0, iterations: 0 }
    }
}

impl Monitor for Terminal {
    fn note(&mut self, line: &str) {
        eprintln!("{line}");
    }

    fn started(&mut self, trainer: &Trainer, cfg: &Config) {
        let steps = cfg.run.steps_to_train();
        let length = if steps < cfg.run.iterations {
            format!("{steps} of the schedule's {} iterations (run.member_iterations)", cfg.run.iterations)
        } else {
            format!("{steps} iterations")
        };
        eprintln!(
            "{} views of {}×{} px, {} Gaussians ({} on the prior, {} from the images), {length}",
            trainer.views().len(),
            trainer.views().image_size().0,
            trainer.views().image_size().1,
            trainer.model().len(),
            trainer.seed_counts().0,
            trainer.seed_counts().1,
        );
        self.iterations = steps;
        self.pb.finish();
        self.pb = bar(steps as u64, "complete");
        self.pb.set_position(trainer.iteration() as u64);
        self.first = trainer.iteration();
        self.began = Instant::now();
    }

    fn stepped(&mut self, trainer: &Trainer, logged: &[StepLog]) {
        self.pb.set_position(trainer.iteration() as u64);
        let rate = (trainer.iteration() - self.first) as f64 / self.began.elapsed().as_secs_f64().max(1e-9);
        let line = |log: &StepLog| {
            format!(
                "loss {:.4} (L1 {:.4}, SSIM {:.3}, FN {:.4}, PA {:.4}) {} G, {:.1} it/s",
                log.loss, log.l1, log.ssim, log.fn_loss, log.pa_loss, log.gaussians, rate
            )
        };
        // Without a terminal the bar is hidden: log a line every 10% instead.
        let tenth = (self.iterations / 10).max(1);
        if self.pb.is_hidden() {
            for log in logged.iter().filter(|l| l.iteration.is_multiple_of(tenth) || l.iteration == self.first + 1) {
                let t = log.times;
                eprintln!(
                    "[{:>6}/{}] {}; ms: field {:.0} render {:.0} losses {:.0} backward {:.0} optim {:.0} densify {:.0} wait {:.0}",
                    log.iteration,
                    self.iterations,
                    line(log),
                    t.field * 1e3,
                    t.render * 1e3,
                    t.losses * 1e3,
                    t.backward * 1e3,
                    t.optimizer * 1e3,
                    t.densify * 1e3,
                    t.wait * 1e3
                );
            }
        }
        if let Some(log) = logged.last() {
            self.pb.set_message(line(log));
        }
    }

    fn should_stop(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }
}

/// Runs the optimisation with a progress bar, checkpoints and Ctrl-C handling; writes outputs.
/// `None` when interrupted (the checkpoint is saved).
pub fn run_completion(
    case: &Case,
    cfg: Config,
    backend: BackendKind,
    out: &Path,
    start: Start,
) -> Result<Option<RunSummary>> {
    let device = backend.device()?.autodiff();
    let mut terminal = Terminal::new();
    match completion::run_completion(case, cfg, device, out, start, &mut terminal)? {
        Outcome::Finished(summary) => {
            terminal.pb.finish_with_message(format!("done in {:.1} s", terminal.began.elapsed().as_secs_f64()));
            Ok(Some(*summary))
        }
        Outcome::Interrupted { checkpoint } => {
            terminal.pb.abandon_with_message(format!("interrupted; checkpoint saved to {}", checkpoint.display()));
            eprintln!(
                "resume with: ctadsa complete --case {} ... --out {} --resume",
                case.dir.display(),
                out.display()
            );
            Ok(None)
        }
    }
}

/// Prints the metrics of a run next to those of the prior alone.
pub fn print_summary(summary: &RunSummary, out: &Path) {
    println!("\nresults in {} (open {} in a browser)", out.display(), out.join("report.html").display());
    println!(
        "  Gaussians: {} (initial {} + {}), mesh: {} triangles at level {:.4}",
        summary.gaussians, summary.n1, summary.n2, summary.mesh_triangles, summary.mc_level
    );
    if let Some(t) = &summary.training_time {
        println!(
            "  training: {:.1} min over {} steps (sum of the step times, across resumes), median step {:.1} ms, \
             {} densification calls (median {:.0} ms)",
            t.steps_s / 60.0,
            t.steps,
            1e3 * t.median_step_s,
            t.densify_calls,
            1e3 * t.densify_median_s
        );
    }
    for m in &summary.seed_members {
        let minutes = m.training_time.as_ref().map_or(0.0, |t| t.steps_s / 60.0);
        println!(
            "  member of seed {} (its density averaged in): {} Gaussians, training {minutes:.1} min",
            m.seed, m.gaussians
        );
    }
    if let Some(m) = &summary.prior_only_member {
        let minutes = m.training_time.as_ref().map_or(0.0, |t| t.steps_s / 60.0);
        println!("  prior-only member (its density averaged in): {} Gaussians, training {minutes:.1} min", m.gaussians);
    }
    if let [first, others @ ..] = summary.ensemble_runs.as_slice() {
        println!(
            "  an ensemble: the mean of the densities of {first} (the numbers above are its own) and {}",
            others.join(", ")
        );
    }
    if let Some(errors) = &summary.pose_errors {
        for e in errors {
            println!(
                "  pose of view {}: reprojection {:.2} px → {:.2} px (rotation error {:.2}°, translation error {:.2} mm)",
                e.view, e.reprojection_before_px, e.reprojection_after_px, e.rotation_error_deg, e.translation_error_mm
            );
        }
    }
    for r in summary.arrival_readings.iter().flatten() {
        let read = match r.median_px {
            0 => "read as it is".to_string(),
            px => format!("read through a {0} × {0} median", 2 * px + 1),
        };
        println!(
            "  arrival map of {}: {:.1} % of its filled pixels off their neighbours' median, {read}",
            r.view,
            100.0 * r.noise
        );
    }
    for r in summary.view_readings.iter().filter(|r| r.noise_sigma > 0.0) {
        let share = r
            .bright
            .map_or(String::new(), |b| format!(" ({:.1} % of its bright value {b:.3})", 100.0 * r.noise_sigma / b));
        let read = match r.reading {
            Reading::PerPixel => "read per pixel",
            Reading::AlongLines => "read along lines",
            Reading::UnderFloorAlongLines => "its pixels under 3 σ read along lines",
        };
        println!("  view {}: noise σ {:.4} image units{share}, {read}", r.view, r.noise_sigma);
    }
    if let Some(dropped) = summary.centreline.arrival_dropped_branches {
        println!(
            "  arrival check (two views): {dropped} new branches left out, their arrival differing between the views"
        );
    }
    if let Some(t) = &summary.topology {
        println!(
            "  topology: clDice {:.3} (topology precision {:.3}, sensitivity {:.3}), {} components against {} \
             (Betti-0 error {})",
            t.cl_dice, t.topology_precision, t.topology_sensitivity, t.components, t.true_components, t.betti0_error
        );
    }
    let (Some(m), Some(p)) = (&summary.metrics, &summary.prior_metrics) else {
        println!("  (no ground truth in the case: no metrics)");
        return;
    };
    println!("\n| region | surface | CD mean (mm) | CD sum (mm) | HD95 (mm) | HD max (mm) |");
    println!("|---|---|---:|---:|---:|---:|");
    let row = |region: &str, what: &str, s: &ctadsa_core::eval::metrics::SurfaceScores| {
        if !s.cd_sum_mm.is_finite() {
            // A surface with no part in the region (the prior in the missing vessels' region).
            println!("| {region} | {what} | — | — | — | — |");
            return;
        }
        println!(
            "| {region} | {what} | {:.3} | {:.3} | {:.3} | {:.3} |",
            s.cd_mean_mm, s.cd_sum_mm, s.hd95_mm, s.hd_mm
        );
    };
    row("overall", "completed", &m.overall);
    row("overall", "prior only", &p.overall);
    if let (Some(a), Some(b)) = (&m.roi, &p.roi) {
        row("ROI (missing vessels)", "completed", a);
        row("ROI (missing vessels)", "prior only", b);
    }
    if let (Some(a), Some(b)) = (&m.prior, &p.prior) {
        row("prior region", "completed", a);
        row("prior region", "prior only", b);
    }
}

pub fn run(args: CompleteArgs) -> Result<()> {
    let case = Case::load(&args.case)?;
    let cfg = Config::load(args.config.as_deref(), &args.overrides)?;
    let out = args.out.clone().unwrap_or_else(|| PathBuf::from("runs").join(&case.file.name));
    let start = match (&args.resume, args.overwrite) {
        (Some(which), _) => Start::Resume(which),
        (None, true) => Start::Overwrite,
        (None, false) => Start::Fresh,
    };
    match run_completion(&case, cfg, args.backend, &out, start)? {
        Some(s) => {
            print_summary(&s, &out);
            Ok(())
        }
        None => bail!("interrupted: the checkpoint is saved; run the same command with --resume to finish"),
    }
}

#[derive(Args)]
pub struct DemoArgs {
    /// Output folder for the synthetic case and the run.
    #[arg(long, default_value = "runs/demo")]
    out: PathBuf,
    /// Backend: ndarray (CPU) or wgpu.
    #[arg(long, value_enum, default_value = "ndarray")]
    backend: BackendKind,
    /// Override a config value of the built-in quick config (repeatable).
    #[arg(long = "set")]
    overrides: Vec<String>,
}

pub fn demo(args: DemoArgs) -> Result<()> {
    // The overrides and the folder are checked before the phantom is made.
    let cfg = Config::quick(&args.overrides)?;
    if args.out.exists() && !args.out.is_dir() {
        bail!("--out {}: is a file; the demo writes a folder (its case and its run)", args.out.display());
    }
    let case_dir = args.out.join("case");
    let started = Instant::now();
    eprintln!("synthesising the built-in phantom case into {}", case_dir.display());
    // The demo owns its case folder, as its run folder: made afresh every time.
    synthesize_replacing(&SynthConfig::demo(), &case_dir, &mut |_| {})?;
    let case = Case::load(&case_dir)?;
    let out = args.out.join("run");
    match run_completion(&case, cfg, args.backend, &out, Start::Overwrite)? {
        Some(s) => {
            print_summary(&s, &out);
            println!("\ndemo finished in {:.0} s (synthesis + completion + outputs)", started.elapsed().as_secs_f64());
            Ok(())
        }
        None => bail!("interrupted"),
    }
}
