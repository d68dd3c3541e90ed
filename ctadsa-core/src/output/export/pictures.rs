//! The pictures a run writes: renders beside their targets, the loss curve, the meshes.

use std::path::Path;

use crate::data::case::Case;
use crate::data::case::images::write_rgb_or_grey;
use crate::data::mesh::TriMesh;
use crate::data::mesh::render_png::{Coloured, OrbitView, standard_views, write_mesh_png};
use crate::data::mesh::split::split_by_distance;
use crate::error::{Result, write_file};
use crate::method::train::{StepLog, Trainer};
use crate::output::plot::{PALETTE, Series, line_plot};

/// `[target | render | |difference|]` of every view, one PNG per view, magnified by an integer
/// factor (nearest neighbour) so that each panel is at least 256 pixels wide.
pub(super) fn write_renders(dir: &Path, case: &Case, trainer: &Trainer, renders: &[Vec<f32>]) -> Result<()> {
    let names: Vec<String> = if trainer.cfg().run.views.is_empty() {
        case.file.views.iter().map(|v| v.name.clone()).collect()
    } else {
        trainer.cfg().run.views.iter().map(|&i| case.file.views[i].name.clone()).collect()
    };
    for ((name, target), render) in names.iter().zip(trainer.images()).zip(renders) {
        let (w, h) = (target.width as usize, target.height as usize);
        let max = target.max().max(render.iter().copied().fold(0.0, f32::max)).max(1e-12);
        let mut rgb = vec![255u8; 3 * w * 3 * h];
        let stride = 3 * w;
        for r in 0..h {
            for c in 0..w {
                let t = target.data[r * w + c] / max;
                let p = render[r * w + c] / max;
                let d = p - t;
                let grey = |v: f32| (255.0 * (1.0 - v.clamp(0.0, 1.0))).round() as u8;
                let px = |k: usize, col: [u8; 3], rgb: &mut Vec<u8>| {
                    let i = 3 * (r * stride + k * w + c);
                    rgb[i..i + 3].copy_from_slice(&col);
                };
                px(0, [grey(t); 3], &mut rgb);
                px(1, [grey(p); 3], &mut rgb);
                // Difference: red where the render is too bright, blue where too dark.
                let m = (255.0 * (1.0 - (d.abs() * 2.0).clamp(0.0, 1.0))).round() as u8;
                px(2, if d > 0.0 { [255, m, m] } else { [m, m, 255] }, &mut rgb);
            }
        }
        // Small detectors are enlarged to ≈ 256 px wide, never past 4,096 px tall (a 1 × 65,536
        // detector would otherwise ask for a 38 GB picture).
        let f = (256 / w.max(1)).min(4096 / h.max(1)).max(1);
        let (big_w, big_h) = (3 * w * f, h * f);
        let mut big = vec![0u8; 3 * big_w * big_h];
        for y in 0..big_h {
            for x in 0..big_w {
                let (i, j) = (3 * (y * big_w + x), 3 * ((y / f) * stride + x / f));
                big[i..i + 3].copy_from_slice(&rgb[j..j + 3]);
            }
        }
        write_rgb_or_grey(&dir.join(format!("renders/{name}.png")), big_w as u32, big_h as u32, big, 3)?;
    }
    Ok(())
}

/// `loss.csv` and `loss.png` (log scale; a term is drawn where it is positive).
pub(super) fn write_loss(dir: &Path, history: &[StepLog]) -> Result<()> {
    let mut csv = String::from("iteration,loss,l1,ssim,fn_loss,pa_loss,gaussians\n");
    for s in history {
        csv.push_str(&format!(
            "{},{},{},{},{},{},{}\n",
            s.iteration, s.loss, s.l1, s.ssim, s.fn_loss, s.pa_loss, s.gaussians
        ));
    }
    write_file(&dir.join("loss.csv"), csv.as_bytes())?;
    // Terms that are never positive (switched off) are left out.
    let pick = |f: fn(&StepLog) -> f64| {
        history.iter().map(|s| (s.iteration as f64, f(s))).filter(|p| p.1 > 0.0).collect::<Vec<_>>()
    };
    let series: Vec<Series> = [
        Series { name: "TOTAL".into(), points: pick(|s| s.loss), rgb: PALETTE[5] },
        Series { name: "L1".into(), points: pick(|s| s.l1), rgb: PALETTE[0] },
        Series { name: "1-SSIM".into(), points: pick(|s| 1.0 - s.ssim), rgb: PALETTE[1] },
        Series { name: "FN".into(), points: pick(|s| s.fn_loss), rgb: PALETTE[2] },
        Series { name: "PA".into(), points: pick(|s| s.pa_loss), rgb: PALETTE[3] },
    ]
    .into_iter()
    .filter(|s| !s.points.is_empty())
    .collect();
    line_plot(&dir.join("loss.png"), "TRAINING LOSS", "ITERATION", "LOSS (LOG)", &series, true)
}

/// `mesh.png` (completed mesh blue, prior red) and, with a prior, `mesh-completion.png` as the
/// paper's Fig. 4: the completed surface where the prior had vessels in red, the new vessels in
/// blue, from four directions.
pub(super) fn write_mesh_pictures(dir: &Path, mesh: &TriMesh, prior: Option<&TriMesh>) -> Result<()> {
    let mut parts = vec![Coloured { mesh, rgb: [60, 120, 220] }];
    if let Some(p) = prior {
        parts.push(Coloured { mesh: p, rgb: [210, 60, 50] });
    }
    write_mesh_png(&dir.join("mesh.png"), &parts, &standard_views(360))?;
    if let Some(p) = prior {
        let (old, new) = split_by_distance(mesh, p, 1.0);
        let mut views = standard_views(320);
        views.push(OrbitView { azimuth_deg: 0.0, elevation_deg: 89.0, width: 320, height: 320 });
        write_mesh_png(
            &dir.join("mesh-completion.png"),
            &[Coloured { mesh: &old, rgb: [210, 60, 50] }, Coloured { mesh: &new, rgb: [60, 120, 220] }],
            &views,
        )?;
    }
    Ok(())
}
