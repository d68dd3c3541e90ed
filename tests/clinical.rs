//! Clinical inputs: DSA runs written as DICOM by dicom-rs are read back into a case that equals
//! the synthetic case they were made from (geometry from the positioner tags, log subtraction,
//! automatic frame choice, orientation), a multi-frame run written by dcmtk is read with its
//! frames and geometry, bad runs give errors that name the problem, and the real TopCoW label
//! volume becomes a prior mesh.

use std::path::{Path, PathBuf};

use ctadsa_core::data::case::images::Image;
use ctadsa_core::data::case::{Case, ViewGeometry};
use ctadsa_core::data::clinical::dsa::Subtraction;
use ctadsa_core::data::clinical::import::{DsaOptions, dsa_view, write_dsa_case};
use ctadsa_core::data::clinical::prior::{LabelPriorOptions, Visibility, prior_from_labels};
use ctadsa_core::data::clinical::simulate::{BOLUS, simulated_run};
use ctadsa_core::data::clinical::xa::{XaRunSpec, read_xa_run, write_xa_run};
use ctadsa_core::data::synth::{Anatomy, SynthConfig, synthesize};
use ctadsa_core::data::tree::prior::PriorThreshold;
use ctadsa_core::data::volume::nifti_io::{read_nifti, write_nifti};
use ctadsa_render::{ConeBeamView, TigreGeometry};

mod scratch;
use scratch::scratch;

fn tmp(name: &str) -> PathBuf {
    scratch(&format!("clinical-{name}"))
}

fn spec(frames: Vec<Vec<u16>>, w: u16, h: u16, g: &TigreGeometry) -> XaRunSpec {
    let image = Image { width: w as u32, height: h as u32, data: vec![0.0; w as usize * h as usize] };
    XaRunSpec { frames, ..simulated_run(&image, g, 1.0, false) }
}

fn tigre(g: &ViewGeometry) -> TigreGeometry {
    match *g {
        ViewGeometry::Tigre { dsd_mm, dso_mm, detector_px, pixel_mm, offset_mm, primary_deg, secondary_deg } => {
            TigreGeometry { dsd_mm, dso_mm, detector_px, pixel_mm, offset_mm, primary_deg, secondary_deg }
        }
        ViewGeometry::Matrix { .. } => panic!("synthetic views are TIGRE"),
    }
}

#[test]
fn dicom_runs_become_the_case_they_were_made_from() {
    let dir = tmp("source-case");
    let cfg = SynthConfig::small_procedural("dicom-source");
    synthesize(&cfg, &dir, &mut |_| {}).expect("synthesis");
    let case = Case::load(&dir).unwrap();
    let max_l = case.images.iter().flat_map(|i| i.data.iter()).copied().fold(0.0f32, f32::max);
    let kappa = 1.2 / max_l;
    let mut views = Vec::new();
    for (i, (entry, img)) in case.file.views.iter().zip(&case.images).enumerate() {
        let g = tigre(&entry.geometry);
        // The frontal run is stored as a viewer facing the patient sees it (mirrored), and says so.
        let mirror = i == 0;
        let mut s = simulated_run(img, &g, kappa, mirror);
        if mirror {
            s.patient_orientation = Some(["L".into(), "F".into()]);
        }
        let path = tmp("runs").join(format!("{}.dcm", entry.name));
        write_xa_run(&path, &s).expect("write DICOM");
        let run = read_xa_run(&path).expect("read DICOM");
        assert_eq!(run.frames.len(), 8);
        assert_eq!(run.mask_frames, vec![0], "mask from the Mask Subtraction Sequence");
        assert_eq!(run.geometry.pixel_mm, g.pixel_mm);
        let v = dsa_view(&run, &entry.name, &DsaOptions::default()).expect("DSA view");
        assert_eq!(v.frames, 3..=5, "frames at ≥ 50 % of the peak contrast (bolus {BOLUS:?})");
        assert_eq!(v.geometry, g, "geometry from the positioner tags");
        views.push(v);
    }
    let out = tmp("imported");
    let prior = case.prior_mesh().unwrap().unwrap();
    write_dsa_case(&out, "imported", &views, Some((&prior, "synthetic prior".into())), 5.0, 0.4, vec![]).unwrap();
    let imported = Case::load(&out).expect("imported case loads");
    // The images equal the source's line integrals up to one scale (κ and the normalisation).
    for (k, (a, b)) in imported.images.iter().zip(&case.images).enumerate() {
        let scale = 1.2 / imported.file.image_values.normalised_by.unwrap() as f32 / max_l;
        let worst = a.data.iter().zip(&b.data).map(|(x, y)| (x - y * scale).abs()).fold(0.0f32, f32::max);
        eprintln!("view {k}: largest difference {worst:.2e} (image max 1)");
        assert!(worst < 2e-3, "view {k}: imported image differs from the source by {worst}");
        let (va, vb): (&ConeBeamView, &ConeBeamView) = (&imported.views.views()[k], &case.views.views()[k]);
        let p = glam::DVec3::new(7.0, -4.0, 3.0);
        assert!((va.project(p).unwrap() - vb.project(p).unwrap()).length() < 1e-9, "view {k}: same projection");
    }
}

fn small_spec() -> XaRunSpec {
    let g = TigreGeometry { detector_px: [4, 4], pixel_mm: [0.3, 0.3], ..TigreGeometry::reference(-90.0) };
    spec(vec![vec![1000; 16], vec![900; 16], vec![800; 16]], 4, 4, &g)
}

fn error_of(s: &XaRunSpec, name: &str) -> String {
    let path = tmp("bad").join(format!("{name}.dcm"));
    write_xa_run(&path, s).unwrap();
    let e = read_xa_run(&path).and_then(|r| dsa_view(&r, name, &DsaOptions::default())).unwrap_err().to_string();
    assert!(e.contains(&format!("{name}.dcm")), "the error names the file: {e}");
    e
}

#[test]
fn missing_tags_wrong_modality_and_single_frames_are_named() {
    let mut s = small_spec();
    s.dsd_mm = None;
    s.pixel_mm = None;
    let e = error_of(&s, "missing");
    assert!(e.contains("(0018,1110)") && e.contains("(0018,1164)"), "{e}");
    assert!(e.contains("DistanceSourceToDetector") && e.contains("ImagerPixelSpacing"), "{e}");

    let mut s = small_spec();
    s.modality = "CT".into();
    let e = error_of(&s, "modality");
    assert!(e.contains("modality is `CT`"), "{e}");

    let mut s = small_spec();
    s.frames.truncate(1);
    s.mask_frame_numbers.clear();
    let e = error_of(&s, "one-frame");
    assert!(e.contains("one frame"), "{e}");
    // An already-subtracted single frame is accepted with subtraction `none`.
    let path = tmp("bad").join("one-frame.dcm");
    let run = read_xa_run(&path).unwrap();
    let o = DsaOptions { subtraction: Subtraction::None, ..DsaOptions::default() };
    assert_eq!(dsa_view(&run, "one", &o).unwrap().image.data, vec![1000.0; 16]);

    let mut s = small_spec();
    s.dso_mm = Some(2000.0);
    let e = error_of(&s, "distances");
    assert!(e.contains("Distance Source to Patient"), "{e}");

    let mut s = small_spec();
    s.primary_deg = Some(1000.0);
    let e = error_of(&s, "angle");
    assert!(e.contains("(0018,1510)") && e.contains("±360"), "{e}");

    let e = read_xa_run(Path::new("/nonexistent/run.dcm")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/run.dcm"), "{e}");
    let junk = tmp("bad").join("junk.dcm");
    std::fs::write(&junk, b"not dicom at all").unwrap();
    let e = read_xa_run(&junk).unwrap_err().to_string();
    assert!(e.contains("junk.dcm") && e.contains("DICOM"), "{e}");
}

fn topcow() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/topcow/topcow_ct_roi_003.nii.gz")
}

#[test]
fn topcow_labels_become_a_prior_mesh() {
    let all = LabelPriorOptions { labels: vec![], min_island_mm2: 0.0, translation_mm: [0.0; 3] };
    let raw = prior_from_labels(&topcow(), &all, &[], Visibility::All).expect("prior");
    let areas: Vec<f64> = raw.mesh.components().iter().map(|c| c.area_mm2()).collect();
    eprintln!("TopCoW: {} voxels, {} triangles, component areas (mm²) {areas:.1?}", raw.voxels, raw.mesh.faces.len());
    assert!(raw.voxels > 1000 && raw.mesh.faces.len() > 1000);
    // A stray labelled voxel far from the vessels (a segmentation speck) is an island: dropped
    // by the 20 mm² threshold, and nothing else is.
    let mut speckled = read_nifti(&topcow()).unwrap();
    let [nx, ny, nz] = speckled.grid.dims;
    let corner = speckled.grid.index(nx - 3, ny - 3, nz - 3);
    assert_eq!(speckled.data[corner], 0.0, "the corner is background");
    speckled.data[corner] = 1.0;
    let speckled_path = tmp("speckled").join("labels.nii.gz");
    write_nifti(&speckled_path, &speckled, "TopCoW roi 003 + one stray voxel (test)").unwrap();
    let noisy = prior_from_labels(&speckled_path, &all, &[], Visibility::All).unwrap();
    let cleaned = prior_from_labels(
        &speckled_path,
        &LabelPriorOptions { min_island_mm2: 20.0, ..all.clone() },
        &[],
        Visibility::All,
    )
    .unwrap();
    assert_eq!(noisy.mesh.components().len(), areas.len() + 1, "the speck is its own component");
    assert_eq!(cleaned.islands_dropped, 1);
    assert_eq!(cleaned.mesh.faces.len(), raw.mesh.faces.len(), "only the speck is removed");
    // One label only: a part of the whole.
    let one = prior_from_labels(&topcow(), &LabelPriorOptions { labels: vec![1], ..all.clone() }, &[], Visibility::All)
        .unwrap();
    assert!(one.voxels > 0 && one.voxels < raw.voxels);
    // An absent label: the error lists the labels present.
    let e = prior_from_labels(&topcow(), &LabelPriorOptions { labels: vec![99], ..all.clone() }, &[], Visibility::All)
        .unwrap_err()
        .to_string();
    assert!(e.contains("99") && e.contains("labels present"), "{e}");
    // Centred on the isocentre and seen by a narrow detector (≈ 14 mm at the isocentre): what the
    // view cannot see is cut away, and what is left projects inside it.
    let (lo, hi) = raw.mesh.bounds_mm().unwrap();
    let centred = LabelPriorOptions { translation_mm: (-(lo + hi) * 0.5).to_array(), ..all };
    let narrow = ConeBeamView::from_tigre(&TigreGeometry {
        detector_px: [64, 64],
        pixel_mm: [0.3, 0.3],
        ..TigreGeometry::reference(-90.0)
    })
    .unwrap();
    let cut =
        prior_from_labels(&topcow(), &centred, std::slice::from_ref(&narrow), Visibility::SeenByEveryView).unwrap();
    assert!(cut.hidden_triangles > 0 && !cut.mesh.is_empty());
    for v in &cut.mesh.vertices {
        let p = narrow.project(*v).unwrap();
        assert!(p.x >= -0.5 && p.x <= 63.5 && p.y >= -0.5 && p.y <= 63.5, "{p:?} outside the detector");
    }
}

/// A synthetic case from the TopCoW labels whose prior leaves out whole branches (the
/// communicating arteries 8, 9, 10): the missing mesh is exactly those labels' surface region,
/// the prior is everything else, and an absent label is an error naming the file.
#[test]
fn topcow_synth_drops_whole_labels_from_the_prior() {
    let labels = |drop: Vec<u32>| SynthConfig {
        name: "topcow-drop".into(),
        anatomy: Anatomy::Labels { path: topcow(), labels: vec![], prior_drop_labels: drop },
        priors: vec![PriorThreshold::DiameterMm(0.0)],
        detector_px: Some(96),
        binning: 2,
        ..SynthConfig::default()
    };
    let dir = tmp("topcow-drop");
    let s = synthesize(&labels(vec![8, 9, 10]), &dir, &mut |_| {}).expect("synthesis");
    // Labels 8, 9, 10 hold 1,223 of the 7,751 labelled voxels (0.504 × 0.504 × 0.75 mm each).
    let voxel_mm3 = 0.504 * 0.504 * 0.75;
    let dropped = s.complete_volume_mm3 - s.prior_volume_mm3;
    eprintln!(
        "complete {:.0} mm³, prior {:.0} mm³, dropped {dropped:.1} mm³",
        s.complete_volume_mm3, s.prior_volume_mm3
    );
    assert!((dropped / voxel_mm3 - 1223.0).abs() < 1.0, "dropped {:.1} voxels", dropped / voxel_mm3);
    let case = Case::load(&dir).unwrap();
    let prior = case.file.prior.as_ref().unwrap();
    assert!(prior.description.contains("[8, 9, 10]"), "{}", prior.description);
    let missing = case.dir.join(case.file.ground_truth.as_ref().unwrap().missing_mesh.as_ref().unwrap());
    assert!(!ctadsa_core::data::mesh::io::read_mesh(&missing).unwrap().is_empty(), "the dropped branches are missing");
    // With nothing dropped and no thickness threshold, nothing is missing.
    let all = synthesize(&labels(vec![]), &tmp("topcow-nodrop"), &mut |_| {}).expect("synthesis");
    assert_eq!(all.prior_volume_mm3, all.complete_volume_mm3);
    let e = synthesize(&labels(vec![14]), &tmp("topcow-drop14"), &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("label 14") && e.contains("topcow_ct_roi_003.nii.gz"), "{e}");
}

/// The registration example of docs/CLINICAL.md §4 is the reference AP view.
#[test]
fn documented_matrix_view_is_the_reference_ap_view() {
    let json = r#"{
        "kind": "matrix",
        "world_to_camera": [[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 500], [0, 0, 0, 1]],
        "focal_px": [1400, 1400],
        "principal_px": [255.5, 255.5],
        "detector_px": [512, 512]
    }"#;
    let g: ViewGeometry = serde_json::from_str(json).unwrap();
    let m = g.to_view().unwrap();
    let t = ConeBeamView::from_tigre(&TigreGeometry::reference(-90.0)).unwrap();
    for p in [glam::DVec3::new(10.0, -20.0, 5.0), glam::DVec3::new(-40.0, 30.0, -25.0)] {
        assert!((m.project(p).unwrap() - t.project(p).unwrap()).length() < 1e-9);
    }
    let docs = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/CLINICAL.md")).unwrap();
    assert!(docs.contains("[[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 500], [0, 0, 0, 1]]"), "docs example changed");
}

/// A multi-frame XA run written by another toolkit: dcmtk's `dump2dcm` makes it in the test from
/// a text dump (12 bits stored in 16, no mask sequence, explicit and implicit VR little endian),
/// and `read_xa_run` reads back every frame and the geometry. Without dcmtk the test prints why
/// and passes, unless `CTADSA_REQUIRE_DICOM_TOOLS=1` (CI installs dcmtk).
#[test]
fn reads_multiframe_xa_written_by_dcmtk() {
    let required = std::env::var("CTADSA_REQUIRE_DICOM_TOOLS").is_ok_and(|v| v == "1");
    if std::process::Command::new("dump2dcm").arg("--version").output().is_err() {
        assert!(!required, "CTADSA_REQUIRE_DICOM_TOOLS=1 but dcmtk's `dump2dcm` is not on the PATH");
        eprintln!("SKIPPED: the dcmtk-written XA fixture was not made: `dump2dcm` is not on the PATH");
        return;
    }
    let dir = tmp("dcmtk");
    std::fs::create_dir_all(&dir).unwrap();
    let (w, h, n) = (48usize, 32usize, 4usize);
    let value = |f: usize, r: usize, c: usize| ((f * 1000 + r * 40 + c) % 4096) as u16;
    let mut raw = Vec::new();
    for f in 0..n {
        for r in 0..h {
            for c in 0..w {
                raw.extend_from_slice(&value(f, r, c).to_le_bytes());
            }
        }
    }
    std::fs::write(dir.join("pixels.raw"), &raw).unwrap();
    let dump = format!(
        "(0008,0016) UI =XRayAngiographicImageStorage\n(0008,0018) UI [1.2.826.0.1.3680043.2.1143.7]\n\
         (0008,0060) CS [XA]\n(0018,1110) DS [1000]\n(0018,1111) DS [750]\n(0018,1164) DS [0.3\\0.2]\n\
         (0018,1510) DS [30.5]\n(0018,1511) DS [-10]\n(0028,0002) US 1\n(0028,0004) CS [MONOCHROME2]\n\
         (0028,0008) IS [{n}]\n(0028,0010) US {h}\n(0028,0011) US {w}\n(0028,0100) US 16\n(0028,0101) US 12\n\
         (0028,0102) US 11\n(0028,0103) US 0\n(7fe0,0010) OW ={}\n",
        dir.join("pixels.raw").display()
    );
    std::fs::write(dir.join("run.dump"), dump).unwrap();
    for (syntax, flag) in [("explicit", "+te"), ("implicit", "+ti")] {
        let file = dir.join(format!("run-{syntax}.dcm"));
        let made = std::process::Command::new("dump2dcm")
            .args([flag, dir.join("run.dump").to_str().unwrap(), file.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(made.status.success(), "dump2dcm: {}", String::from_utf8_lossy(&made.stderr));
        let run = read_xa_run(&file).unwrap_or_else(|e| panic!("{syntax} VR: {e}"));
        assert_eq!((run.columns, run.rows, run.frames.len()), (w as u32, h as u32, n), "{syntax} VR");
        for (f, frame) in run.frames.iter().enumerate() {
            for (i, &v) in frame.iter().enumerate() {
                assert_eq!(v, value(f, i / w, i % w) as f32, "{syntax} VR: frame {f}, pixel {i}");
            }
        }
        let g = run.geometry;
        assert_eq!((g.dsd_mm, g.dso_mm, g.primary_deg, g.secondary_deg), (1000.0, 750.0, 30.5, -10.0));
        assert_eq!(g.pixel_mm, [0.2, 0.3], "[column, row] spacing from (0018,1164) row\\column");
        assert!(run.mask_frames.is_empty(), "no Mask Subtraction Sequence in this file");
    }
    std::fs::remove_dir_all(&dir).ok();
}
