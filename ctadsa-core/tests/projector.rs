//! The voxel projector used to synthesise DSA views: analytic checks (sphere chords, detector
//! mass, point phantom in the renderer's conventions) and plastimatch's DRR as an outside peer.

use ctadsa_core::data::projector::project_volume;
use ctadsa_core::data::tree::Segment;
use ctadsa_core::data::volume::rasterize::rasterize_segments;
use ctadsa_core::data::volume::{Grid, Volume};
use ctadsa_render::{ConeBeamView, TigreGeometry};
use glam::DVec3;

/// A uniform ball (value 1 per mm) of radius `r` at `centre`, partial-volume sampled.
fn ball(centre: DVec3, r: f64, h: f64, half: f64) -> Volume<f32> {
    let n = (2.0 * half / h).round() as usize;
    let grid = Grid { dims: [n; 3], spacing_mm: [h; 3], origin_mm: [-half; 3] };
    let seg = Segment { child: 1, start_mm: centre, end_mm: centre, start_radius_mm: r, end_radius_mm: r };
    rasterize_segments(&[seg], grid, 4)
}

fn geometry(primary_deg: f64, n: u32, pitch: f64) -> TigreGeometry {
    TigreGeometry { detector_px: [n, n], pixel_mm: [pitch, pitch], ..TigreGeometry::reference(primary_deg) }
}

#[test]
fn uniform_sphere_chords_within_one_percent() {
    // The peers' sphere: R = 30 mm, value 1 per mm, here at 0.5 mm voxels.
    let r = 30.0;
    let vol = ball(DVec3::ZERO, r, 0.5, 32.0);
    for angle in [-90.0, 0.0, 33.0] {
        let geom = geometry(angle, 150, 0.6);
        let view = ConeBeamView::from_tigre(&geom).unwrap();
        let img = &project_volume(&vol, &[view])[0];
        let mut checked = 0;
        let mut worst = 0.0f64;
        for row in 0..150u32 {
            for col in 0..150u32 {
                let d = view.pixel_ray(col as f64, row as f64);
                let s = view.source_mm();
                let delta = (-s).cross(d).length(); // distance of the ray from the centre
                // Away from the rim: there the chord changes by more than a voxel within half a
                // voxel of ray offset, and the voxelised sphere, not the projector, sets the error.
                if delta < 0.6 * r {
                    let chord = 2.0 * (r * r - delta * delta).sqrt();
                    let got = img[(row * 150 + col) as usize] as f64;
                    worst = worst.max(((got - chord) / chord).abs());
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000);
        assert!(worst < 0.01, "angle {angle}: worst chord error {worst:.4}");
    }
}

#[test]
fn detector_total_is_volume_integral_times_magnification_squared() {
    let vol = ball(DVec3::new(3.0, -2.0, 1.0), 12.0, 0.5, 16.0);
    let integral: f64 = vol.data.iter().map(|&v| v as f64).sum::<f64>() * 0.125;
    let geom = geometry(-90.0, 200, 0.25);
    let view = ConeBeamView::from_tigre(&geom).unwrap();
    let img = &project_volume(&vol, &[view])[0];
    let total: f64 = img.iter().map(|&v| v as f64).sum::<f64>() * 0.25 * 0.25;
    // The ball's centre is at depth 500 − (−2) … the y offset moves it along the AP axis.
    let depth = view.to_camera(DVec3::new(3.0, -2.0, 1.0)).z;
    let m = geom.dsd_mm / depth;
    let rel = total / (integral * m * m) - 1.0;
    assert!(rel.abs() < 5e-3, "Σ p·px² / (∫f·M²) − 1 = {rel:+.2e}");
}

#[test]
fn point_phantom_lands_where_the_renderer_view_projects_it() {
    for (angle, p) in [(-90.0, DVec3::new(7.0, 3.0, -9.0)), (0.0, DVec3::new(-4.0, 11.0, 6.0))] {
        let geom = TigreGeometry { offset_mm: [2.5, -1.5], ..geometry(angle, 128, 0.5) };
        let view = ConeBeamView::from_tigre(&geom).unwrap();
        // A smooth blob (σ = 1 mm), so that pixel sampling does not bias its centroid.
        let grid = Grid { dims: [140; 3], spacing_mm: [0.2; 3], origin_mm: [-14.0; 3] };
        let mut vol = Volume::<f32>::zeros(grid);
        for i in 0..140 {
            for j in 0..140 {
                for k in 0..140 {
                    let d2 = (grid.centre_mm(i, j, k) - p).length_squared();
                    vol.data[grid.index(i, j, k)] = (-0.5 * d2).exp() as f32;
                }
            }
        }
        let img = &project_volume(&vol, &[view])[0];
        let (mut sw, mut sc, mut sr) = (0.0, 0.0, 0.0);
        for (i, &v) in img.iter().enumerate() {
            sw += v as f64;
            sc += v as f64 * (i % 128) as f64;
            sr += v as f64 * (i / 128) as f64;
        }
        let predicted = view.project(p).unwrap();
        assert!(
            (sc / sw - predicted.x).abs() < 0.05 && (sr / sw - predicted.y).abs() < 0.05,
            "angle {angle}: centroid ({:.3}, {:.3}) vs projection {predicted}",
            sc / sw,
            sr / sw
        );
    }
}

#[test]
fn agrees_with_plastimatch_drr_per_pixel() {
    if std::process::Command::new("plastimatch").arg("--version").output().is_err() {
        if std::env::var("CTADSA_REQUIRE_PLASTIMATCH").is_ok_and(|v| v == "1") {
            panic!("CTADSA_REQUIRE_PLASTIMATCH=1 but plastimatch is not installed");
        }
        eprintln!("SKIPPED: plastimatch is not installed (apt-get install plastimatch); peer check not run");
        return;
    }
    // An off-centre ellipsoid-like blob made of two balls, so orientation errors show.
    let mut vol = ball(DVec3::new(6.0, -4.0, 3.0), 7.0, 0.5, 20.0);
    let second = ball(DVec3::new(-8.0, 5.0, -6.0), 4.0, 0.5, 20.0);
    for (a, b) in vol.data.iter_mut().zip(&second.data) {
        *a = (*a + 2.0 * *b).min(2.0);
    }
    let temp = tempfile::tempdir().unwrap();
    let dir = temp.path().to_path_buf();
    let mha = dir.join("v.mha");
    ctadsa_core::bench::plastimatch::write_mha(&mha, &vol).unwrap();
    for angle in [-90.0f64, 0.0, -45.0] {
        let geom = geometry(angle, 120, 0.6);
        let view = ConeBeamView::from_tigre(&geom).unwrap();
        let ours = &project_volume(&vol, &[view])[0];
        let a = angle.to_radians();
        let out_dir = dir.join(format!("a{}", angle as i32));
        std::fs::create_dir_all(&out_dir).unwrap();
        let status = std::process::Command::new("plastimatch")
            .arg("drr")
            .args(["-A", "cpu", "-i", "exact", "-P", "none", "-t", "pfm"])
            .args(["--sad", "500", "--sid", "700", "-r", "120 120", "-z", "72 72"])
            .args(["-n", &format!("{} {} 0", a.cos(), a.sin()), "--vup", "0 0 1", "-o", "0 0 0"])
            .arg("-O")
            .arg(out_dir.join("drr"))
            .arg(&mha)
            .output()
            .unwrap();
        assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
        let pfm = std::fs::read_dir(&out_dir)
            .unwrap()
            .filter_map(|e| e.ok().map(|e| e.path()))
            .find(|p| p.extension().is_some_and(|e| e == "pfm"))
            .expect("a .pfm image");
        let bytes = std::fs::read(&pfm).unwrap();
        let header_end = bytes.iter().enumerate().filter(|(_, b)| **b == b'\n').nth(2).unwrap().0 + 1;
        let text = String::from_utf8_lossy(&bytes[..header_end]).to_string();
        let little = text.lines().nth(2).unwrap().trim().parse::<f64>().unwrap() < 0.0;
        let theirs: Vec<f64> = bytes[header_end..]
            .chunks_exact(4)
            .map(|c| {
                let b = [c[0], c[1], c[2], c[3]];
                (if little { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) }) as f64 * 10.0
            })
            .collect();
        assert_eq!(theirs.len(), 120 * 120);
        // plastimatch writes its PFM rows top to bottom (row 0 = the detector's `vup` edge).
        let max = ours.iter().copied().fold(0.0f32, f32::max) as f64;
        let mut worst = 0.0f64;
        for r in 0..120 {
            for c in 0..120 {
                let t = theirs[r * 120 + c];
                let o = ours[r * 120 + c] as f64;
                if t.max(o) > 0.1 * max {
                    worst = worst.max((o - t).abs() / t.max(o));
                }
            }
        }
        println!("angle {angle}: worst per-pixel relative difference {worst:.2e} (pixels above 10% of the max)");
        assert!(worst < 0.01, "angle {angle}: ours and plastimatch differ by {worst:.3} somewhere");
    }
}
