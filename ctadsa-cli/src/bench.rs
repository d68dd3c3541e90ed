//! `ctadsa bench`: timings of the renderer and the voxel projector, printed as tables.
//!
//! - `render`: forward and backward of the Gaussian renderer (CPU kernels, and the burn op on the
//!   chosen backend) on a vessel-like scene, with Gaussian–ray pairs per second;
//! - `projector`: our voxel projector against plastimatch's CPU DRR on the same volume and
//!   geometry (when `plastimatch` is installed).

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use ctadsa_core::bench::render::{ProjectorBench, RenderBench, bench_projector, bench_render};
use ctadsa_core::bench::{TrainBenchReport, TrainBenchSettings, peak_rss_mib};

use crate::backend::BackendKind;

#[derive(Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
    /// Worker threads (rayon) for the CPU kernels, 1 to 1,024 (each is an OS thread with its own
    /// stack: 10^5 of them exhaust the machine).
    #[arg(long, default_value_t = 2, global = true, value_parser = in_range(1, 1_024))]
    threads: usize,
}

/// The most timed steps a bench accepts (a step takes tens of ms to seconds).
const MAX_STEPS: u64 = 100_000;

/// A flag's value parser accepting the integers `lo..=hi`: clap refuses others naming the flag.
fn in_range(lo: u64, hi: u64) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::new().range(lo..=hi)
}

#[derive(Subcommand)]
enum BenchWhat {
    /// Forward and backward of the Gaussian renderer on a vessel-like scene.
    Render {
        /// Number of Gaussians (1 to 10^7).
        #[arg(long, default_value_t = 60_000, value_parser = in_range(1, 10_000_000))]
        gaussians: usize,
        /// Detector size (pixels per side, 8 to 4,096) of each of the two views (AP, LAT).
        #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(8..=4096))]
        size: u32,
        /// Timed repetitions (1 to 1,000, after one warm-up); the median is reported.
        #[arg(long, default_value_t = 5, value_parser = in_range(1, 1_000))]
        repeats: usize,
        /// Also time the burn op on this backend (including tensor transfers).
        #[arg(long, value_enum)]
        backend: Option<BackendKind>,
    },
    /// Time per optimisation step by stage (field, render, losses, backward, optimiser, densify)
    /// on a case, with the peak memory; steady-state steps (every loss term active from the first).
    Train {
        /// Case folder (default: the demo case, synthesised into a temporary folder).
        #[arg(long)]
        case: Option<std::path::PathBuf>,
        /// Configuration (default: the built-in quick config).
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// Override a config value (repeatable), e.g. init.n1=30000.
        #[arg(long = "set")]
        overrides: Vec<String>,
        /// Timed steps (1 to 100,000, after 2 warm-up steps); the mean per stage is reported.
        #[arg(long, default_value_t = 20, value_parser = in_range(1, MAX_STEPS))]
        steps: usize,
        /// Backend.
        #[arg(long, value_enum, default_value = "ndarray")]
        backend: BackendKind,
        /// Further steps with every kernel launch timed on the device (wgpu; a table of device
        /// time per kernel). Timing each launch slows the pass: these steps are timed apart.
        #[arg(long, default_value_t = 0, value_parser = in_range(0, MAX_STEPS))]
        device_timed_steps: usize,
    },
    /// One table of the training step for the configurations users run: the quick config on the
    /// demo case, and the paper's schedule (one 512² view per step, ~60k Gaussians) with the
    /// hash table at 2^19 and at the reference's 2^20, and at 100k Gaussians (the size a paper
    /// run grows to); the peak memory is reset before each row (Linux).
    TrainSuite {
        /// Timed steps per row (1 to 100,000, after 2 warm-up steps).
        #[arg(long, default_value_t = 5, value_parser = in_range(1, MAX_STEPS))]
        steps: usize,
        /// Backend of every row.
        #[arg(long, value_enum, default_value = "ndarray")]
        backend: BackendKind,
    },
    /// Our voxel projector against plastimatch's DRR on the same vessel volume.
    Projector {
        /// Voxels along each side of the cubic volume (8 to 1,024).
        #[arg(long, default_value_t = 256, value_parser = in_range(8, 1_024))]
        voxels: usize,
        /// Detector size (pixels per side, 8 to 4,096).
        #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(8..=4096))]
        size: u32,
    },
}

fn print_render(r: &RenderBench, backend: Option<BackendKind>) {
    println!(
        "scene: {} Gaussians along a procedural tree, 2 views of {s} × {s} px, k = {}, {} threads",
        r.gaussians,
        r.k_sigma,
        rayon::current_num_threads(),
        s = r.size
    );
    println!(
        "pairs evaluated (pixels inside k-σ footprints): {} ({:.1} per Gaussian per view)",
        r.pairs,
        r.pairs as f64 / (2.0 * r.gaussians as f64)
    );
    println!(
        "pixel lanes the forward kernel evaluates (8-lane vectors over footprint boxes): {} ({:.2} per pair)",
        r.lanes,
        r.lanes as f64 / r.pairs as f64
    );
    let pairs = r.pairs as f64;
    println!();
    println!("| stage | time per call (ms) | Gaussian-ray pairs / s (M) |");
    println!("|---|---:|---:|");
    println!("| forward, CPU kernel | {:.1} | {:.0} |", r.forward_s * 1e3, pairs / r.forward_s / 1e6);
    println!("| backward, CPU kernel | {:.1} | {:.0} |", r.backward_s * 1e3, pairs / r.backward_s / 1e6);
    if let (Some(t), Some(b)) = (r.op_s, backend) {
        println!(
            "| forward + backward, burn op on {b:?} (incl. transfers, autodiff) | {:.1} | {:.0} (per pass pair) |",
            t * 1e3,
            pairs / t / 1e6
        );
    }
    if let Some(m) = peak_rss_mib() {
        println!("\npeak resident memory (scene, images, kernels): {m:.0} MiB");
    }
    let p = &r.peers;
    let rays = 2.0 * (r.size * r.size) as f64;
    println!();
    println!(
        "Peers, same scene and views: the Gaussians voxelised on {}³ voxels of {:.3} mm ({:.0} ms), then projected.",
        p.voxels,
        p.voxel_mm,
        p.voxelize_s * 1e3
    );
    println!();
    println!("| projector (both views) | time (ms) | rays / s (M) |");
    println!("|---|---:|---:|");
    println!(
        "| ctadsa Gaussian forward (exact line integrals, this table's first row) | {:.1} | {:.1} |",
        r.forward_s * 1e3,
        rays / r.forward_s / 1e6
    );
    println!(
        "| ctadsa voxel projector (exact traversal) | {:.1} | {:.1} |",
        p.projector_s * 1e3,
        rays / p.projector_s / 1e6
    );
    match (p.plastimatch_s, p.plastimatch_relative_l2) {
        (Some(t), Some(l2)) => {
            println!(
                "| plastimatch 1.9 drr -A cpu -i exact (process per view, incl. file I/O) | {:.1} | {:.1} |",
                t * 1e3,
                rays / t / 1e6
            );
            println!(
                "\nrelative L2 difference, plastimatch's DRR of the voxelised scene against the Gaussian render: {l2:.2e} \
                 (voxelisation at {:.2} mm of Gaussians with σ ≈ 0.3 mm)",
                p.voxel_mm
            );
        }
        _ => println!("| plastimatch | not installed (apt-get install plastimatch) | |"),
    }
}

fn print_projector(r: &ProjectorBench) {
    println!(
        "volume: {v}³ voxels of {:.3} mm (procedural tree), one AP view of {s} × {s} px",
        r.voxel_mm,
        v = r.voxels,
        s = r.size
    );
    println!();
    println!("| projector | time per view (s) | rays / s (M) |");
    println!("|---|---:|---:|");
    let rays = (r.size * r.size) as f64;
    println!(
        "| ctadsa voxel projector (exact traversal, {} threads) | {:.3} | {:.2} |",
        rayon::current_num_threads(),
        r.projector_s,
        rays / r.projector_s / 1e6
    );
    match (r.plastimatch_s, r.relative_l2) {
        (Some(t), Some(l2)) => {
            println!(
                "| plastimatch 1.9 drr -A cpu -i exact (process, incl. file I/O) | {t:.3} | {:.2} |",
                rays / t / 1e6
            );
            println!("\nrelative L2 difference between the two images: {l2:.2e}");
        }
        _ => println!("| plastimatch | not installed (apt-get install plastimatch) | |"),
    }
}

/// Runs `ctadsa_core::bench::bench_train` on `case` (default: the demo case, synthesised) with
/// `config` (default: the built-in quick one) and prints its tables.
pub fn bench_train(
    case: Option<std::path::PathBuf>,
    config: Option<std::path::PathBuf>,
    overrides: &[String],
    settings: TrainBenchSettings,
    backend: BackendKind,
) -> Result<TrainBenchReport> {
    use ctadsa_core::config::Config;
    use ctadsa_core::data::case::Case;
    // The demo case lives in a temporary folder, removed when the bench returns.
    let demo_dir;
    let case_dir = match case {
        Some(d) => d,
        None => {
            demo_dir = tempfile::Builder::new().prefix("ctadsa-bench-case-").tempdir()?;
            let d = demo_dir.path().to_path_buf();
            eprintln!("synthesising the demo case into {}", d.display());
            ctadsa_core::data::synth::synthesize(&ctadsa_core::data::synth::SynthConfig::demo(), &d, &mut |_| {})?;
            d
        }
    };
    let case = Case::load(&case_dir)?;
    let cfg = match &config {
        Some(p) => Config::load(Some(p), overrides)?,
        None => Config::quick(overrides)?,
    };
    let device = backend.device()?.autodiff();
    let r = ctadsa_core::bench::bench_train(&case, cfg.clone(), device, settings)?;
    let (w, h) = case.views.image_size();
    println!(
        "case {} ({} views of {w} × {h} px before binning), config {}, {} Gaussians, hash table 2^{} × {} levels, {backend:?}, {} threads",
        case.file.name,
        case.views.len(),
        config.as_ref().map_or("quick (built in)".to_string(), |p| p.display().to_string()),
        r.gaussians,
        cfg.field.encoding.log2_table,
        cfg.field.encoding.levels,
        rayon::current_num_threads()
    );
    println!("views rendered per step: {}", r.views_per_step);
    println!();
    println!("| stage | ms per step |");
    println!("|---|---:|");
    let s = r.stages;
    for (name, v) in [
        ("field (hash grid + MLP)", s.field),
        ("render (forward)", s.render),
        ("losses (L1, SSIM, FN, PA)", s.losses),
        ("backward (all)", s.backward),
        ("optimiser (Adam)", s.optimizer),
        ("waiting for the device (the loss read)", s.wait),
    ] {
        println!("| {name} | {:.1} |", v * 1e3);
    }
    println!("| **total per step** | **{:.1}** |", r.per_step_s * 1e3);
    let p = &r.densify_plan;
    println!(
        "| densify (one call: {} cloned, {} split, {} pruned) | {:.1} |",
        p.cloned,
        p.split,
        p.pruned,
        r.densify_s * 1e3
    );
    println!("| initialisation (once) | {:.0} |", r.init_s * 1e3);
    let n = r.steps as f64;
    let t = r.transfers;
    println!();
    println!(
        "device work per step: {:.1} kernel launches, {:.2} blocking reads ({:.0} bytes), {:.2} uploads ({:.0} bytes)",
        r.launches.as_ref().map_or(0.0, |l| l.total() as f64 / n),
        t.reads as f64 / n,
        t.read_bytes as f64 / n,
        t.uploads as f64 / n,
        t.upload_bytes as f64 / n
    );
    if let Some(timed) = &r.device_timed {
        let k = r.device_timed_steps.max(1) as f64;
        println!();
        println!(
            "device time per kernel ({} steps, each launch timed on the device: {:.2} ms per step in all)",
            r.device_timed_steps,
            timed.total_device_time().as_secs_f64() * 1e3 / k
        );
        println!();
        println!("| kernel | launches per step | device ms per step |");
        println!("|---|---:|---:|");
        let mut rows: Vec<(&String, &u64)> = timed.counts.iter().collect();
        let time = |name: &str| timed.device_time.get(name).map_or(0.0, |d| d.as_secs_f64());
        rows.sort_by(|a, b| time(b.0).total_cmp(&time(a.0)));
        for (name, count) in rows {
            println!("| {name} | {:.1} | {:.3} |", *count as f64 / k, time(name) * 1e3 / k);
        }
    }
    if let Some(m) = peak_rss_mib() {
        println!("\npeak resident memory: {m:.0} MiB");
    }
    Ok(r)
}

pub fn run(args: BenchArgs) -> Result<()> {
    rayon::ThreadPoolBuilder::new().num_threads(args.threads).build_global().context("setting up threads")?;
    match args.what {
        BenchWhat::Render { gaussians, size, repeats, backend } => {
            let device = match backend {
                Some(b) => Some(b.device()?.autodiff()),
                None => None,
            };
            print_render(&bench_render(gaussians, size, repeats, device.as_ref())?, backend);
            Ok(())
        }
        BenchWhat::Projector { voxels, size } => {
            print_projector(&bench_projector(voxels, size)?);
            Ok(())
        }
        BenchWhat::Train { case, config, overrides, steps, backend, device_timed_steps } => {
            bench_train(case, config, &overrides, TrainBenchSettings { steps, device_timed_steps }, backend).map(|_| ())
        }
        BenchWhat::TrainSuite { steps, backend } => crate::bench_suite::train_suite(steps, args.threads, backend),
    }
}
