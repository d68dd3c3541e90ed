//! `ctadsa bench`: timings of the renderer and the voxel projector, printed as tables.
//!
//! - `render`: forward and backward of the Gaussian renderer (CPU kernels, and the burn op on the
//!   chosen backend) on a vessel-like scene, with Gaussian–ray pairs per second;
//! - `projector`: our voxel projector against plastimatch's CPU DRR on the same volume and
//!   geometry (when `plastimatch` is installed).

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::tensor::{Tensor, TensorData};
use clap::{Args, Subcommand};
use ctadsa_core::data::projector::project_volume;
use ctadsa_core::data::tree::gaussians::{GaussianArrays, tree_gaussians};
use ctadsa_core::data::tree::procedural::ProceduralTree;
use ctadsa_core::data::volume::{Grid, Volume};
use ctadsa_render::cpu::{self, HostGaussians};
use ctadsa_render::{ConeBeamView, Gaussians, RenderSettings, TigreGeometry, ViewSet, VoxelGrid};

use crate::backend::BackendKind;
use ctadsa_core::bench::TrainBenchSettings;

#[derive(Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    what: BenchWhat,
    /// Worker threads (rayon) for the CPU kernels.
    #[arg(long, default_value_t = 2, global = true)]
    threads: usize,
}

#[derive(Subcommand)]
enum BenchWhat {
    /// Forward and backward of the Gaussian renderer on a vessel-like scene.
    Render {
        /// Number of Gaussians.
        #[arg(long, default_value_t = 60_000)]
        gaussians: usize,
        /// Detector size (pixels per side) of each of the two views (AP, LAT).
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Timed repetitions (after one warm-up); the median is reported.
        #[arg(long, default_value_t = 5)]
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
        /// Timed steps (after 2 warm-up steps); the mean per stage is reported.
        #[arg(long, default_value_t = 20)]
        steps: usize,
        /// Backend.
        #[arg(long, value_enum, default_value = "ndarray")]
        backend: BackendKind,
        /// Further steps with every kernel launch timed on the device (wgpu; a table of device
        /// time per kernel). Timing each launch slows the pass: these steps are timed apart.
        #[arg(long, default_value_t = 0)]
        device_timed_steps: usize,
    },
    /// One table of the training step for the configurations users run: the quick config on the
    /// demo case, and the paper's schedule (one 512² view per step, ~60k Gaussians) with the
    /// hash table at 2^19 and at the reference's 2^20, and at 100k Gaussians (the size a paper
    /// run grows to); each row in its own process (so peak memory is per row).
    TrainSuite {
        /// Timed steps per row (after 2 warm-up steps).
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Backend of every row.
        #[arg(long, value_enum, default_value = "ndarray")]
        backend: BackendKind,
    },
    /// Our voxel projector against plastimatch's DRR on the same vessel volume.
    Projector {
        /// Voxels along each side of the cubic volume.
        #[arg(long, default_value_t = 256)]
        voxels: usize,
        /// Detector size (pixels per side).
        #[arg(long, default_value_t = 512)]
        size: u32,
    },
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = f(); // warm-up
    let mut times = Vec::with_capacity(repeats);
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        out = f();
        times.push(t.elapsed().as_secs_f64());
    }
    (median(times), out)
}

/// Peak resident memory of this process (MiB), from /proc (Linux).
pub fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// The vessel-like benchmark scene: Gaussians along a procedural tree filling ≈ 120 mm.
pub fn vessel_scene(count: usize) -> Result<GaussianArrays> {
    let tree =
        ProceduralTree { terminals: 400, domain_mm: [60.0, 60.0, 50.0], seed: 7, ..Default::default() }.generate()?;
    Ok(tree_gaussians(&tree, count, 0.3))
}

/// The benchmark's two views (AP, LAT): reference geometry, `size²` pixels over 256 mm.
fn two_view_geometries(size: u32) -> [TigreGeometry; 2] {
    [-90.0, 0.0].map(|a| TigreGeometry {
        detector_px: [size, size],
        pixel_mm: [256.0 / size as f64, 256.0 / size as f64],
        ..TigreGeometry::reference(a)
    })
}

fn two_views(size: u32) -> Result<ViewSet> {
    let views =
        two_view_geometries(size).iter().map(ConeBeamView::from_tigre).collect::<std::result::Result<Vec<_>, _>>()?;
    Ok(ViewSet::new(views)?)
}

fn bench_render(gaussians: usize, size: u32, repeats: usize, backend: Option<BackendKind>) -> Result<()> {
    let scene = vessel_scene(gaussians)?;
    let views = two_views(size)?;
    let k = RenderSettings::default().k_sigma;
    let host = HostGaussians {
        means: &scene.means,
        scales: &scene.scales,
        rotations: &scene.rotations,
        densities: &scene.densities,
    };
    let pairs = cpu::count_pairs(&host, views.packed(), k);
    let (t_fwd, image) = time(repeats, || cpu::render(&host, views.packed(), k));
    let grad: Vec<f32> = image.iter().map(|v| 1.0 + 0.1 * v).collect();
    let (t_bwd, _) = time(repeats, || cpu::render_backward(&host, views.packed(), k, &grad));
    println!(
        "scene: {} Gaussians along a procedural tree, 2 views of {size} × {size} px, k = {k}, {} threads",
        scene.len(),
        rayon::current_num_threads()
    );
    println!(
        "pairs evaluated (pixels inside k-σ footprints): {pairs} ({:.1} per Gaussian per view)",
        pairs as f64 / (2.0 * scene.len() as f64)
    );
    let lanes = cpu::count_lanes(&host, views.packed(), k);
    println!(
        "pixel lanes the forward kernel evaluates (8-lane vectors over footprint boxes): {lanes} ({:.2} per pair)",
        lanes as f64 / pairs as f64
    );
    println!();
    println!("| stage | time per call (ms) | Gaussian-ray pairs / s (M) |");
    println!("|---|---:|---:|");
    println!("| forward, CPU kernel | {:.1} | {:.0} |", t_fwd * 1e3, pairs as f64 / t_fwd / 1e6);
    println!("| backward, CPU kernel | {:.1} | {:.0} |", t_bwd * 1e3, pairs as f64 / t_bwd / 1e6);
    if let Some(b) = backend {
        let device = b.device()?.autodiff();
        let n = scene.len();
        let t = |v: &Vec<f32>, cols: usize| {
            let shape = if cols == 1 { vec![n] } else { vec![n, cols] };
            TensorData::new(v.clone(), shape)
        };
        let g = Gaussians {
            means: Tensor::from_data(t(&scene.means, 3), &device).require_grad(),
            scales: Tensor::from_data(t(&scene.scales, 3), &device).require_grad(),
            rotations: Tensor::from_data(t(&scene.rotations, 4), &device).require_grad(),
            densities: Tensor::from_data(t(&scene.densities, 1), &device).require_grad(),
        };
        let settings = RenderSettings::default();
        let (t_op, _) = time(repeats, || {
            let img = ctadsa_render::render(&g, &views, &settings).expect("valid scene");
            let grads = img.sum().backward();
            let d = g.means.grad(&grads).expect("gradient");
            d.into_data()
        });
        println!(
            "| forward + backward, burn op on {b:?} (incl. transfers, autodiff) | {:.1} | {:.0} (per pass pair) |",
            t_op * 1e3,
            pairs as f64 / t_op / 1e6
        );
    }
    if let Some(m) = peak_rss_mib() {
        println!("\npeak resident memory (scene, images, kernels): {m:.0} MiB");
    }
    render_peers(&host, size, k, t_fwd, &image)
}

/// The peers of `bench render`, in the same run: the scene voxelised (our CPU `voxelize`, 256³
/// voxels over 130 mm) and projected into the same two views by our voxel projector and by
/// plastimatch's CPU DRR, against the Gaussian forward's time `t_fwd` (s) and `image`.
fn render_peers(host: &HostGaussians, size: u32, k: f32, t_fwd: f64, image: &[f32]) -> Result<()> {
    const N: usize = 256;
    let h = 130.0 / N as f64;
    let grid = Grid { dims: [N; 3], spacing_mm: [h; 3], origin_mm: [-65.0; 3] };
    let vgrid = VoxelGrid { origin_mm: [-65.0; 3], spacing_mm: [h as f32; 3], dims: [N as u32; 3] };
    let (t_vox, data) = time(1, || cpu::voxelize(host, &vgrid, k));
    let vol = Volume { grid, index_to_world: grid.index_to_world(), data };
    let geoms = two_view_geometries(size);
    let views: Vec<ConeBeamView> = geoms.iter().map(ConeBeamView::from_tigre).collect::<std::result::Result<_, _>>()?;
    let (t_ours, _) = time(1, || project_volume(&vol, &views));
    let rays = 2.0 * (size * size) as f64;
    println!();
    println!(
        "Peers, same scene and views: the Gaussians voxelised on {N}³ voxels of {h:.3} mm ({:.0} ms), then projected.",
        t_vox * 1e3
    );
    println!();
    println!("| projector (both views) | time (ms) | rays / s (M) |");
    println!("|---|---:|---:|");
    println!(
        "| ctadsa Gaussian forward (exact line integrals, this table's first row) | {:.1} | {:.1} |",
        t_fwd * 1e3,
        rays / t_fwd / 1e6
    );
    println!("| ctadsa voxel projector (exact traversal) | {:.1} | {:.1} |", t_ours * 1e3, rays / t_ours / 1e6);
    let work = std::env::temp_dir().join(format!("ctadsa-bench-render-{}", std::process::id()));
    std::fs::create_dir_all(&work)?;
    let mha = work.join("scene.mha");
    write_mha(&mha, &vol)?;
    let mut theirs = Vec::new();
    let mut t_theirs = 0.0;
    for g in &geoms {
        match plastimatch_drr(&mha, g, &work)? {
            Some((img, t)) => {
                theirs.extend(img);
                t_theirs += t;
            }
            None => break,
        }
    }
    std::fs::remove_dir_all(&work).ok();
    if theirs.len() != image.len() {
        println!("| plastimatch | not installed (apt-get install plastimatch) | |");
        return Ok(());
    }
    println!(
        "| plastimatch 1.9 drr -A cpu -i exact (process per view, incl. file I/O) | {:.1} | {:.1} |",
        t_theirs * 1e3,
        rays / t_theirs / 1e6
    );
    let num: f64 = theirs.iter().zip(image).map(|(a, b)| (*a as f64 - *b as f64).powi(2)).sum();
    let den: f64 = image.iter().map(|b| (*b as f64).powi(2)).sum();
    println!(
        "\nrelative L2 difference, plastimatch's DRR of the voxelised scene against the Gaussian render: {:.2e} \
         (voxelisation at {h:.2} mm of Gaussians with σ ≈ 0.3 mm)",
        (num / den).sqrt()
    );
    Ok(())
}

fn bench_train(
    case: Option<std::path::PathBuf>,
    config: Option<std::path::PathBuf>,
    overrides: &[String],
    settings: TrainBenchSettings,
    backend: BackendKind,
) -> Result<()> {
    use ctadsa_core::config::Config;
    use ctadsa_core::data::case::Case;
    let case_dir = match case {
        Some(d) => d,
        None => {
            let d = std::env::temp_dir().join(format!("ctadsa-bench-case-{}", std::process::id()));
            eprintln!("synthesising the demo case into {}", d.display());
            ctadsa_core::data::synth::synthesize(&crate::complete::demo_case_config(), &d, &mut |_| {})?;
            d
        }
    };
    let case = Case::load(&case_dir)?;
    let cfg = match &config {
        Some(p) => Config::load(Some(p), overrides)?,
        None => Config::from_toml_str(crate::complete::QUICK_TOML, "configs/quick.toml", overrides)?,
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
    Ok(())
}

/// Writes a MetaImage (`.mha`, float, x fastest) of `volume` for plastimatch.
fn write_mha(path: &Path, volume: &Volume<f32>) -> Result<()> {
    let g = volume.grid;
    let [nx, ny, nz] = g.dims;
    let centre0 = g.centre_mm(0, 0, 0);
    let mut bytes = format!(
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
         TransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = {} {} {}\nElementSpacing = {} {} {}\n\
         DimSize = {nx} {ny} {nz}\nElementType = MET_FLOAT\nElementDataFile = LOCAL\n",
        centre0.x, centre0.y, centre0.z, g.spacing_mm[0], g.spacing_mm[1], g.spacing_mm[2]
    )
    .into_bytes();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                bytes.extend(volume.data[g.index(i, j, k)].to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// Reads a plastimatch PFM image (float; plastimatch writes rows top to bottom).
fn read_pfm(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        while at < bytes.len() && bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        let start = at;
        while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
            at += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..at]).to_string());
    }
    at += 1;
    if fields[0] != "Pf" {
        bail!("{}: not a greyscale PFM", path.display());
    }
    let (w, h): (usize, usize) = (fields[1].parse()?, fields[2].parse()?);
    let little = fields[3].parse::<f64>()? < 0.0;
    let mut data = vec![0.0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let o = at + 4 * (r * w + c);
            let b = [bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]];
            let v = if little { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) };
            data[r * w + c] = v;
        }
    }
    Ok((w, h, data))
}

/// Runs plastimatch's CPU DRR of `mha` for `geom` (secondary angle 0); returns the image in
/// value × mm, row 0 at the top, and the wall time. `None` when plastimatch is not installed.
pub fn plastimatch_drr(mha: &Path, geom: &TigreGeometry, work: &Path) -> Result<Option<(Vec<f32>, f64)>> {
    if std::process::Command::new("plastimatch").arg("--version").output().is_err() {
        return Ok(None);
    }
    let a = geom.primary_deg.to_radians();
    let [w, h] = geom.detector_px;
    let prefix = work.join("drr");
    let start = Instant::now();
    let out = std::process::Command::new("plastimatch")
        .arg("drr")
        .args(["-A", "cpu", "-i", "exact", "-P", "none", "-t", "pfm"])
        .args(["--sad", &geom.dso_mm.to_string(), "--sid", &geom.dsd_mm.to_string()])
        .args(["-r", &format!("{h} {w}")])
        .args(["-z", &format!("{} {}", h as f64 * geom.pixel_mm[1], w as f64 * geom.pixel_mm[0])])
        .args(["-n", &format!("{} {} 0", a.cos(), a.sin())])
        .args(["--vup", "0 0 1", "-o", "0 0 0"])
        .arg("-O")
        .arg(&prefix)
        .arg(mha)
        .output()
        .context("running plastimatch drr")?;
    let elapsed = start.elapsed().as_secs_f64();
    if !out.status.success() {
        bail!("plastimatch drr failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    let pfm = std::fs::read_dir(work)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .find(|p| p.extension().is_some_and(|e| e == "pfm"))
        .context("plastimatch wrote no .pfm")?;
    let (pw, ph, mut data) = read_pfm(&pfm)?;
    std::fs::remove_file(&pfm).ok();
    if (pw, ph) != (w as usize, h as usize) {
        bail!("plastimatch image is {pw} × {ph}, expected {w} × {h}");
    }
    // plastimatch integrates in cm for per-mm values: × 10 gives value × mm.
    data.iter_mut().for_each(|v| *v *= 10.0);
    Ok(Some((data, elapsed)))
}

fn bench_projector(voxels: usize, size: u32) -> Result<()> {
    if !(8..=1024).contains(&voxels) || !(8..=4096).contains(&size) {
        bail!("--voxels must be in 8..=1024 and --size in 8..=4096, got {voxels} and {size}");
    }
    let tree =
        ProceduralTree { terminals: 300, domain_mm: [60.0, 60.0, 50.0], seed: 7, ..Default::default() }.generate()?;
    let h = 130.0 / voxels as f64;
    let grid = Grid { dims: [voxels; 3], spacing_mm: [h; 3], origin_mm: [-65.0; 3] };
    let vol = ctadsa_core::data::volume::rasterize::rasterize_segments(&tree.segments(), grid, 1);
    let geom = TigreGeometry {
        detector_px: [size, size],
        pixel_mm: [256.0 / size as f64, 256.0 / size as f64],
        ..TigreGeometry::reference(-90.0)
    };
    let view = ConeBeamView::from_tigre(&geom)?;
    let (t_ours, ours) = time(3, || project_volume(&vol, &[view]));
    println!("volume: {voxels}³ voxels of {h:.3} mm (procedural tree), one AP view of {size} × {size} px");
    println!();
    println!("| projector | time per view (s) | rays / s (M) |");
    println!("|---|---:|---:|");
    let rays = (size * size) as f64;
    println!(
        "| ctadsa voxel projector (exact traversal, {} threads) | {t_ours:.3} | {:.2} |",
        rayon::current_num_threads(),
        rays / t_ours / 1e6
    );
    let work = std::env::temp_dir().join(format!("ctadsa-bench-{}", std::process::id()));
    std::fs::create_dir_all(&work)?;
    let mha = work.join("volume.mha");
    write_mha(&mha, &vol)?;
    match plastimatch_drr(&mha, &geom, &work)? {
        Some((theirs, t)) => {
            let num: f64 = theirs.iter().zip(&ours[0]).map(|(a, b)| (*a as f64 - *b as f64).powi(2)).sum();
            let den: f64 = ours[0].iter().map(|b| (*b as f64).powi(2)).sum();
            println!(
                "| plastimatch 1.9 drr -A cpu -i exact (process, incl. file I/O) | {t:.3} | {:.2} |",
                rays / t / 1e6
            );
            println!("\nrelative L2 difference between the two images: {:.2e}", (num / den).sqrt());
        }
        None => println!("| plastimatch | not installed (apt-get install plastimatch) | |"),
    }
    std::fs::remove_dir_all(&work).ok();
    Ok(())
}

pub fn run(args: BenchArgs) -> Result<()> {
    rayon::ThreadPoolBuilder::new().num_threads(args.threads).build_global().context("setting up threads")?;
    match args.what {
        BenchWhat::Render { gaussians, size, repeats, backend } => bench_render(gaussians, size, repeats, backend),
        BenchWhat::Projector { voxels, size } => bench_projector(voxels, size),
        BenchWhat::Train { case, config, overrides, steps, backend, device_timed_steps } => {
            bench_train(case, config, &overrides, TrainBenchSettings { steps, device_timed_steps }, backend)
        }
        BenchWhat::TrainSuite { steps, backend } => crate::bench_suite::train_suite(steps, args.threads, backend),
    }
}
