//! The renderer and the voxel projector timed on a vessel-like scene, with their peers:
//! `ctadsa bench render` and `ctadsa bench projector` print what these return.

use std::time::Instant;

use burn::tensor::{Device, Tensor, TensorData};
use ctadsa_render::cpu::{self, HostGaussians};
use ctadsa_render::{ConeBeamView, Gaussians, RenderSettings, TigreGeometry, ViewSet, VoxelGrid};

use super::plastimatch::{plastimatch_drr, write_mha};
use crate::data::projector::project_volume;
use crate::data::tree::gaussians::{GaussianArrays, tree_gaussians};
use crate::data::tree::procedural::ProceduralTree;
use crate::data::volume::{Grid, Volume};
use crate::error::{CoreError, Result};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The median wall time (s) of `repeats` calls after one warm-up, and the last result.
fn time<T>(repeats: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut out = f();
    let mut times = Vec::with_capacity(repeats.max(1));
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        out = f();
        times.push(t.elapsed().as_secs_f64());
    }
    (median(times), out)
}

/// The vessel-like benchmark scene: `count` Gaussians along a procedural tree filling ≈ 120 mm.
pub fn vessel_scene(count: usize) -> Result<GaussianArrays> {
    let tree =
        ProceduralTree { terminals: 400, domain_mm: [60.0, 60.0, 50.0], seed: 7, ..Default::default() }.generate()?;
    Ok(tree_gaussians(&tree, count, 0.3))
}

/// The benchmark's two views (AP, LAT): reference geometry, `size²` pixels over 256 mm.
pub fn two_view_geometries(size: u32) -> [TigreGeometry; 2] {
    [-90.0, 0.0].map(|a| TigreGeometry {
        detector_px: [size, size],
        pixel_mm: [256.0 / size as f64, 256.0 / size as f64],
        ..TigreGeometry::reference(a)
    })
}

fn views_of(geometries: &[TigreGeometry]) -> Result<Vec<ConeBeamView>> {
    Ok(geometries.iter().map(ConeBeamView::from_tigre).collect::<std::result::Result<Vec<_>, _>>()?)
}

/// What [`bench_render`] measured (times in s, medians).
#[derive(Debug, Clone)]
pub struct RenderBench {
    pub gaussians: usize,
    /// Pixels per side of each of the two views.
    pub size: u32,
    pub k_sigma: f32,
    /// Gaussian–ray pairs inside the k-σ footprints, and the pixel lanes the forward evaluates.
    pub pairs: u64,
    pub lanes: u64,
    pub forward_s: f64,
    pub backward_s: f64,
    /// Forward + backward of the burn op on the given device (with transfers and autodiff).
    pub op_s: Option<f64>,
    pub peers: RenderPeers,
}

/// The same scene voxelised and projected by the voxel projector and by plastimatch.
#[derive(Debug, Clone)]
pub struct RenderPeers {
    pub voxels: usize,
    pub voxel_mm: f64,
    pub voxelize_s: f64,
    /// Our voxel projector, both views.
    pub projector_s: f64,
    /// plastimatch's CPU DRR, both views (a process per view, with file I/O), and the relative
    /// L2 difference of its image to the Gaussian render; `None` without plastimatch.
    pub plastimatch_s: Option<f64>,
    pub plastimatch_relative_l2: Option<f64>,
}

/// The Gaussian renderer's CPU kernels on `gaussians` Gaussians and two `size²` views, and with
/// `device` the burn op's forward + backward; then the peers ([`RenderPeers`]).
pub fn bench_render(gaussians: usize, size: u32, repeats: usize, device: Option<&Device>) -> Result<RenderBench> {
    let scene = vessel_scene(gaussians)?;
    let views = ViewSet::new(views_of(&two_view_geometries(size))?)?;
    let k = RenderSettings::default().k_sigma;
    let host = HostGaussians {
        means: &scene.means,
        scales: &scene.scales,
        rotations: &scene.rotations,
        densities: &scene.densities,
    };
    let pairs = cpu::count_pairs(&host, views.packed(), k);
    let lanes = cpu::count_lanes(&host, views.packed(), k);
    let (forward_s, image) = time(repeats, || cpu::render(&host, views.packed(), k));
    let grad: Vec<f32> = image.iter().map(|v| 1.0 + 0.1 * v).collect();
    let (backward_s, _) = time(repeats, || cpu::render_backward(&host, views.packed(), k, &grad));
    let op_s = match device {
        Some(device) => Some(time_op(&scene, &views, device, repeats)?),
        None => None,
    };
    let peers = render_peers(&host, size, k, &image)?;
    Ok(RenderBench { gaussians: scene.len(), size, k_sigma: k, pairs, lanes, forward_s, backward_s, op_s, peers })
}

fn time_op(scene: &GaussianArrays, views: &ViewSet, device: &Device, repeats: usize) -> Result<f64> {
    let n = scene.len();
    let t = |v: &Vec<f32>, cols: usize| {
        let shape = if cols == 1 { vec![n] } else { vec![n, cols] };
        TensorData::new(v.clone(), shape)
    };
    let g = Gaussians {
        means: Tensor::from_data(t(&scene.means, 3), device).require_grad(),
        scales: Tensor::from_data(t(&scene.scales, 3), device).require_grad(),
        rotations: Tensor::from_data(t(&scene.rotations, 4), device).require_grad(),
        densities: Tensor::from_data(t(&scene.densities, 1), device).require_grad(),
    };
    let settings = RenderSettings::default();
    let mut failed = None;
    let (s, _) = time(repeats, || match ctadsa_render::render(&g, views, &settings) {
        Ok(img) => {
            let grads = img.sum().backward();
            g.means.grad(&grads).map(|d| d.into_data())
        }
        Err(e) => {
            failed = Some(e);
            None
        }
    });
    match failed {
        Some(e) => Err(CoreError::from(e)),
        None => Ok(s),
    }
}

/// The scene voxelised (our CPU `voxelize`, 256³ voxels over 130 mm) and projected into the same
/// two views by our voxel projector and by plastimatch's CPU DRR; `image` is the Gaussian render.
fn render_peers(host: &HostGaussians, size: u32, k: f32, image: &[f32]) -> Result<RenderPeers> {
    const N: usize = 256;
    let h = 130.0 / N as f64;
    let grid = Grid { dims: [N; 3], spacing_mm: [h; 3], origin_mm: [-65.0; 3] };
    let vgrid = VoxelGrid { origin_mm: [-65.0; 3], spacing_mm: [h as f32; 3], dims: [N as u32; 3] };
    let (voxelize_s, data) = time(1, || cpu::voxelize(host, &vgrid, k));
    let volume = Volume { grid, index_to_world: grid.index_to_world(), data };
    let geometries = two_view_geometries(size);
    let views = views_of(&geometries)?;
    let (projector_s, _) = time(1, || project_volume(&volume, &views));
    let (plastimatch_s, plastimatch_relative_l2) = match plastimatch_images(&volume, &geometries)? {
        Some((theirs, s)) if theirs.len() == image.len() => (Some(s), Some(relative_l2(&theirs, image))),
        _ => (None, None),
    };
    Ok(RenderPeers { voxels: N, voxel_mm: h, voxelize_s, projector_s, plastimatch_s, plastimatch_relative_l2 })
}

/// plastimatch's DRRs of `volume` for `geometries`, one after another, and their summed time.
fn plastimatch_images(volume: &Volume<f32>, geometries: &[TigreGeometry]) -> Result<Option<(Vec<f32>, f64)>> {
    // Removed when dropped, on an error too; a fresh name per call.
    let temp = tempfile::Builder::new()
        .prefix("ctadsa-bench-peers-")
        .tempdir()
        .map_err(|e| CoreError::io(&std::env::temp_dir(), e))?;
    let work = temp.path();
    let mha = work.join("volume.mha");
    write_mha(&mha, volume)?;
    let mut images = Vec::new();
    let mut seconds = 0.0;
    let mut all = true;
    for g in geometries {
        match plastimatch_drr(&mha, g, work)? {
            Some((image, s)) => {
                images.extend(image);
                seconds += s;
            }
            None => {
                all = false;
                break;
            }
        }
    }
    Ok(all.then_some((images, seconds)))
}

/// `‖a − b‖ / ‖b‖`.
fn relative_l2(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
    let den: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

/// What [`bench_projector`] measured (s).
#[derive(Debug, Clone)]
pub struct ProjectorBench {
    pub voxels: usize,
    pub voxel_mm: f64,
    pub size: u32,
    /// Our voxel projector, one AP view (median of 3).
    pub projector_s: f64,
    /// plastimatch's CPU DRR of the same volume and view, and the relative L2 difference of the
    /// two images; `None` without plastimatch.
    pub plastimatch_s: Option<f64>,
    pub relative_l2: Option<f64>,
}

/// The voxel projector against plastimatch on a rasterised procedural tree of `voxels³` voxels
/// over 130 mm and one AP view of `size²` pixels.
pub fn bench_projector(voxels: usize, size: u32) -> Result<ProjectorBench> {
    if !(8..=1024).contains(&voxels) || !(8..=4096).contains(&size) {
        return Err(CoreError::invalid(format!(
            "voxels must be in 8..=1024 and the detector size in 8..=4096, got {voxels} and {size}"
        )));
    }
    let tree =
        ProceduralTree { terminals: 300, domain_mm: [60.0, 60.0, 50.0], seed: 7, ..Default::default() }.generate()?;
    let h = 130.0 / voxels as f64;
    let grid = Grid { dims: [voxels; 3], spacing_mm: [h; 3], origin_mm: [-65.0; 3] };
    let volume = crate::data::volume::rasterize::rasterize_segments(&tree.segments(), grid, 1);
    let geometry = TigreGeometry {
        detector_px: [size, size],
        pixel_mm: [256.0 / size as f64, 256.0 / size as f64],
        ..TigreGeometry::reference(-90.0)
    };
    let view = ConeBeamView::from_tigre(&geometry)?;
    let (projector_s, ours) = time(3, || project_volume(&volume, &[view]));
    let (plastimatch_s, relative_l2) = match plastimatch_images(&volume, &[geometry])? {
        Some((theirs, s)) => (Some(s), Some(self::relative_l2(&theirs, &ours[0]))),
        None => (None, None),
    };
    Ok(ProjectorBench { voxels, voxel_mm: h, size, projector_s, plastimatch_s, relative_l2 })
}
