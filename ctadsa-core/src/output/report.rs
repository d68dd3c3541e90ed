//! One self-contained HTML page for a finished run: the case (views, geometry, prior, provenance),
//! renders against targets, the completed mesh (prior part and new vessels in two colours), the
//! loss curve, metrics, pose corrections and the configuration. Images are embedded as data
//! URIs, so the page can be mailed or archived on its own.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use base64::Engine as _;
use serde_json::Value;

use crate::data::case::{CASE_FILE, CaseFile, ViewGeometry};
use crate::data::mesh::TriMesh;
use crate::data::mesh::io::read_mesh;
use crate::data::mesh::split::split_by_distance;
use crate::data::run_folder::read_run_summary;
use crate::data::vessel_evidence::{POOLED_NOISE_SHARE, POOLED_NOISE_SHARE_TWO_VIEWS};
use crate::error::{CoreError, Result, read_file, write_file};
use crate::eval::metrics::nearest_points;
use crate::output::confidence::{
    CONFIDENCE_BINS, MESH_CONFIDENCE, confidence_rgb, faces_by_confidence, read_mesh_confidence,
};
use crate::output::viewer::{ViewerPart, viewer_html};

/// The report's file name inside the run folder.
pub const REPORT_FILE: &str = "report.html";

/// `text` safe inside HTML text and quoted attribute values.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;").replace('\'', "&#39;")
}

/// A summary value as text for the page: a number as it is, anything else (a crafted summary
/// may hold strings or objects where numbers belong) escaped.
fn text(v: &Value) -> String {
    match v {
        Value::Number(n) => n.to_string(),
        Value::String(s) => escape(s),
        other => escape(&other.to_string()),
    }
}

fn png_tag(path: &Path, alt: &str) -> Result<String> {
    let bytes = read_file(path)?;
    let b64 = base64::engine::general_purpose::STANDARD.encode(bytes);
    Ok(format!("<img alt=\"{}\" src=\"data:image/png;base64,{b64}\">", escape(alt)))
}

fn num(v: &Value) -> String {
    match v.as_f64() {
        Some(x) if x.is_finite() => format!("{x:.3}"),
        Some(_) => "∞".into(),
        None => "–".into(),
    }
}

fn metrics_rows(html: &mut String, label: &str, scores: &Value) {
    for (region, key) in [("overall", "overall"), ("ROI (missing vessels)", "roi"), ("prior region", "prior")] {
        let s = &scores[key];
        if s.is_null() {
            continue;
        }
        // Non-finite distances (an empty region) are stored as null.
        let d = |v: &Value| if v.is_null() { "∞".to_string() } else { num(v) };
        let _ = write!(
            html,
            "<tr><td>{label}</td><td>{region}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            d(&s["cd_mean_mm"]),
            d(&s["cd_sum_mm"]),
            d(&s["hd95_mm"]),
            d(&s["hd_mm"])
        );
    }
}

/// A written report: its path, and the files it found but could not read (each with the reason),
/// whose parts the page leaves out and names at its top.
#[derive(Debug, Clone)]
pub struct WrittenReport {
    pub path: PathBuf,
    pub left_out: Vec<String>,
}

/// `read(path)` for a part of the report: `None` where the file is absent, and where it is
/// present but unreadable also a note in `left_out` naming it.
fn optional<T>(path: &Path, left_out: &mut Vec<String>, read: impl FnOnce(&Path) -> Result<T>) -> Option<T> {
    if !path.exists() {
        return None;
    }
    read(path)
        .map_err(|e| {
            // The error names its file, as the library's errors do; else the note names it.
            let (message, name) = (e.to_string(), path.display().to_string());
            left_out.push(if message.contains(&name) { message } else { format!("{name}: {message}") });
        })
        .ok()
}

/// Writes `RUN_DIR/report.html`. Needs `summary.json` (written by every finished run); every
/// other piece is shown when present, and one present but unreadable is named on the page and
/// in [`WrittenReport::left_out`].
pub fn write_report(run_dir: &Path) -> Result<WrittenReport> {
    let summary: Value = read_run_summary(run_dir)?;
    let mut left_out = Vec::new();
    let case_dir = summary["case_dir"].as_str().map(PathBuf::from);
    let case: Option<CaseFile> = case_dir.as_ref().and_then(|d| {
        optional(&d.join(CASE_FILE), &mut left_out, |p| {
            let text = String::from_utf8(read_file(p)?).map_err(|_| CoreError::format(p, "not UTF-8 text"))?;
            CaseFile::parse(&text, p)
        })
    });
    let title = case.as_ref().map_or("ctadsa run".to_string(), |c| format!("ctadsa — {}", c.name));
    let mut body = String::new();
    inputs(&mut body, case.as_ref());
    arrival_readings(&mut body, &summary);
    view_readings(&mut body, &summary);
    renders(&mut body, run_dir)?;
    completed_tree(&mut body, run_dir)?;
    interactive_view(&mut body, run_dir, case.as_ref(), case_dir.as_deref(), &mut left_out);
    metrics(&mut body, &summary);
    centreline(&mut body, run_dir, &summary)?;
    poses(&mut body, run_dir, &summary)?;
    if run_dir.join("loss.png").exists() {
        body.push_str("<h2>Training loss</h2>");
        body.push_str(&png_tag(&run_dir.join("loss.png"), "loss curve")?);
    }
    if let Some(cfg) = optional(&run_dir.join("config.toml"), &mut left_out, read_file) {
        let _ = write!(body, "<h2>Configuration</h2><pre>{}</pre>", escape(&String::from_utf8_lossy(&cfg)));
    }
    let mut html = String::new();
    header(&mut html, &title, run_dir, case_dir.as_deref(), &summary);
    if !left_out.is_empty() {
        html.push_str(
            "<div class=\"left-out\"><p><b>Left out of this page</b> (files present but unreadable):</p><ul>",
        );
        for note in &left_out {
            let _ = write!(html, "<li><code>{}</code></li>", escape(note));
        }
        html.push_str("</ul></div>");
    }
    html.push_str(&body);
    // Marks the page once every image has decoded (checked by the report test in a browser).
    html.push_str(
        "<script>window.addEventListener('load',()=>{const i=[...document.images];\
         document.body.dataset.imagesTotal=i.length;\
         document.body.dataset.imagesLoaded=i.filter(x=>x.complete&&x.naturalWidth>0).length;});</script>",
    );
    html.push_str("</body></html>\n");
    let path = run_dir.join(REPORT_FILE);
    write_file(&path, html.as_bytes())?;
    Ok(WrittenReport { path, left_out })
}

/// The page head, style and the run's one-line description.
fn header(html: &mut String, title: &str, run_dir: &Path, case_dir: Option<&Path>, summary: &Value) {
    let _ = write!(
        html,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>\
         body{{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}}\
         img{{max-width:100%;border:1px solid #ccc;margin:4px 0}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}td:first-child,th:first-child{{text-align:left}}\
         pre{{background:#f5f5f5;padding:1em;overflow:auto}}.key span{{padding:0 .6em;color:#fff}}</style></head><body>",
        escape(title)
    );
    let _ = write!(
        html,
        "<h1>{}</h1><p>Run folder: <code>{}</code>",
        escape(title),
        escape(&run_dir.display().to_string())
    );
    if let Some(d) = case_dir {
        let _ = write!(html, "; case: <code>{}</code>", escape(&d.display().to_string()));
    }
    let _ = write!(
        html,
        ". {} iterations, {} Gaussians ({} seeded on the prior, {} from the images), {} triangles.</p>",
        text(&summary["iterations"]),
        text(&summary["gaussians"]),
        text(&summary["n1"]),
        text(&summary["n2"]),
        text(&summary["mesh_triangles"])
    );
    if let Some(runs) = summary["ensemble_runs"].as_array().filter(|r| !r.is_empty()) {
        let names: Vec<String> = runs.iter().map(|r| format!("<code>{}</code>", text(r))).collect();
        let _ = write!(
            html,
            "<p>An ensemble of {} finished runs (<code>ctadsa ensemble</code>): {}. The density, the surface, the \
             centreline and the metrics are of the mean of their densities; the Gaussians, renders, loss and \
             configuration shown are the first run's.</p>",
            runs.len(),
            names.join(", ")
        );
    }
}

/// One line describing a view's geometry.
fn geometry_text(geometry: &ViewGeometry) -> String {
    match geometry {
        ViewGeometry::Tigre { dsd_mm, dso_mm, detector_px, pixel_mm, primary_deg, secondary_deg, .. } => format!(
            "C-arm: primary {primary_deg:.1}°, secondary {secondary_deg:.1}°, DSD {dsd_mm} mm, DSO {dso_mm} mm, \
             {} × {} px of {:.3} × {:.3} mm",
            detector_px[0], detector_px[1], pixel_mm[0], pixel_mm[1]
        ),
        ViewGeometry::Matrix { detector_px, focal_px, .. } => format!(
            "registered world-to-camera matrix, focal {:.1} px, {} × {} px",
            focal_px[0], detector_px[0], detector_px[1]
        ),
    }
}

/// The case: views with their geometry, the prior, image units and provenance.
fn inputs(html: &mut String, case: Option<&CaseFile>) {
    html.push_str("<h2>Inputs</h2>");
    let Some(c) = case else {
        html.push_str("<p>The case folder named in summary.json could not be read; inputs not shown.</p>");
        return;
    };
    html.push_str("<table><tr><th>view</th><th>image</th><th>geometry</th></tr>");
    for v in &c.views {
        let g = geometry_text(&v.geometry);
        let _ =
            write!(html, "<tr><td>{}</td><td>{}</td><td>{}</td></tr>", escape(&v.name), escape(&v.image), escape(&g));
    }
    html.push_str("</table>");
    if let Some(p) = &c.prior {
        let _ = write!(html, "<p>Prior: <code>{}</code> — {}</p>", escape(&p.mesh), escape(&p.description));
    }
    let _ = write!(html, "<p>Images: {}. Source: {}.</p>", escape(&c.image_values.units), escape(&c.provenance.source));
    if !c.provenance.notes.is_empty() {
        html.push_str("<details><summary>Provenance notes</summary><ul>");
        for n in &c.provenance.notes {
            let _ = write!(html, "<li>{}</li>", escape(n));
        }
        html.push_str("</ul></details>");
    }
}

/// How the run read each view's arrival map (`arrival_readings` of summary.json), when the case
/// has them.
fn arrival_readings(html: &mut String, summary: &Value) {
    let Some(readings) = summary["arrival_readings"].as_array() else { return };
    html.push_str(
        "<h2>Arrival maps</h2><p>A map is noisy when many of its filled pixels have a frame other than \
         the median of their 3 × 3 neighbours (<code>run.arrival_noisy_share</code>); a noisy one is read \
         through that median.</p><table><tr><th>view</th><th>filled pixels off their neighbours' median</th>\
         <th>read</th></tr>",
    );
    for r in readings {
        let noise =
            r["noise"].as_f64().filter(|x| x.is_finite()).map_or("–".into(), |x| format!("{:.1} %", 100.0 * x));
        let read = match r["median_px"].as_u64() {
            Some(0) => "as it is".to_string(),
            Some(px) => format!("through a {0} × {0} median", 2 * px + 1),
            None => "–".into(),
        };
        let _ = write!(html, "<tr><td>{}</td><td>{noise}</td><td>{read}</td></tr>", text(&r["view"]));
    }
    html.push_str("</table>");
}

/// How the run read each view for its vessels (`view_readings` of summary.json): per pixel, or
/// along lines where the noise of a view of the run is high against its vessels.
fn view_readings(html: &mut String, summary: &Value) {
    let Some(readings) = summary["view_readings"].as_array().filter(|r| !r.is_empty()) else { return };
    let _ = write!(
        html,
        "<h2>Views: noise</h2><p>A view whose noise (σ, estimated from the view) exceeds {:.1} % of its \
         bright value (the 99.5th percentile of its pixels above 3 σ; {:.1} % in a run with two views) is \
         read along lines of pixels, which finds thin vessels under the per-pixel noise floor: with two \
         views every pixel, with three or more only the pixels under 3 σ (the others keep their own values, \
         and the vessels their edges). A run reads its views one way: where any view is read along lines, \
         so is every view with noise. Otherwise views are read pixel by pixel, above 3 σ.</p><table><tr><th>view</th>\
         <th>noise σ (image units)</th><th>bright value</th><th>σ / bright</th><th>read</th></tr>",
        100.0 * POOLED_NOISE_SHARE,
        100.0 * POOLED_NOISE_SHARE_TWO_VIEWS
    );
    for r in readings {
        let number = |v: &Value| v.as_f64().filter(|x| x.is_finite());
        let (sigma, bright) = (number(&r["noise_sigma"]), number(&r["bright"]));
        let show = |x: Option<f64>| x.map_or("–".into(), |x| format!("{x:.4}"));
        let share = match (sigma, bright) {
            (Some(s), Some(b)) if b > 0.0 => format!("{:.1} %", 100.0 * s / b),
            _ => "–".into(),
        };
        let read = match r["reading"].as_str() {
            Some("per_pixel") => "per pixel",
            Some("along_lines") => "along lines",
            Some("under_floor_along_lines") => "under 3 σ along lines",
            _ => "–",
        };
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{share}</td><td>{read}</td></tr>",
            text(&r["view"]),
            show(sigma),
            show(bright)
        );
    }
    html.push_str("</table>");
}

/// Target | render | difference of every view (`renders/*.png`).
fn renders(html: &mut String, run_dir: &Path) -> Result<()> {
    html.push_str("<h2>Renders against targets</h2><p>Each row: target | render of the completed model | difference (red: render too bright, blue: too dark).</p>");
    let mut renders: Vec<PathBuf> = std::fs::read_dir(run_dir.join("renders"))
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|e| e == "png")).collect()
        })
        .unwrap_or_default();
    renders.sort();
    for r in &renders {
        let name = r.file_stem().and_then(|s| s.to_str()).unwrap_or("view");
        let _ = write!(
            html,
            "<h3>{}</h3>{}",
            escape(name),
            png_tag(r, &format!("view {name}: target, render, difference"))?
        );
    }
    Ok(())
}

/// The completed mesh, prior part and new vessels in two colours.
fn completed_tree(html: &mut String, run_dir: &Path) -> Result<()> {
    html.push_str("<h2>Completed vessel tree</h2>");
    let fig4 = run_dir.join("mesh-completion.png");
    if fig4.exists() {
        html.push_str("<p class=\"key\"><span style=\"background:#d23c32\">prior (CTA)</span> <span style=\"background:#3c78dc\">new vessels (from the DSA views)</span> — views from AP, LAT, oblique and above.</p>");
        html.push_str(&png_tag(&fig4, "completed mesh: prior part and new vessels")?);
    } else if run_dir.join("mesh.png").exists() {
        html.push_str("<p>Completed surface (blue) with the prior (red).</p>");
        html.push_str(&png_tag(&run_dir.join("mesh.png"), "completed mesh and prior")?);
    }
    Ok(())
}

/// The completed surface as an interactive 3-D view: where the prior had vessels in grey, the
/// new vessels coloured by confidence (`mesh-confidence.ply`; without it the prior red and the
/// new vessels blue, as `mesh-completion.png`).
fn interactive_view(
    html: &mut String,
    run_dir: &Path,
    case: Option<&CaseFile>,
    case_dir: Option<&Path>,
    left_out: &mut Vec<String>,
) {
    let Some(mesh_path) = ["obj", "ply", "stl"].iter().map(|e| run_dir.join(format!("mesh.{e}"))).find(|p| p.exists())
    else {
        return;
    };
    let Some(mesh) = optional(&mesh_path, left_out, read_mesh) else { return };
    let prior = match (case.and_then(|c| c.prior.as_ref()), case_dir) {
        (Some(p), Some(d)) => optional(&d.join(&p.mesh), left_out, read_mesh),
        _ => None,
    };
    html.push_str("<h3>Interactive view</h3>");
    let (old, new) = match &prior {
        Some(p) => split_by_distance(&mesh, p, 1.0),
        None => (TriMesh::default(), mesh),
    };
    // The new vessels coloured by confidence where the run wrote it (`mesh-confidence.ply`).
    let by_confidence =
        optional(&run_dir.join(MESH_CONFIDENCE), left_out, read_mesh_confidence).map(|(scored, confidence)| {
            let nearest = nearest_points(&new.vertices, &scored.vertices);
            let at: Vec<f32> = nearest.iter().map(|&(_, i)| confidence.get(i).copied().unwrap_or(1.0)).collect();
            faces_by_confidence(&new, &at)
        });
    let names: Vec<String> = (0..CONFIDENCE_BINS)
        .map(|k| {
            format!(
                "new vessels, confidence {:.1}–{:.1}",
                k as f64 / CONFIDENCE_BINS as f64,
                (k + 1) as f64 / CONFIDENCE_BINS as f64
            )
        })
        .collect();
    // The prior grey beside the confidence colours (red to green), red beside plain blue.
    let prior_rgb = if by_confidence.is_some() { [150, 150, 150] } else { [210, 60, 50] };
    let mut parts = vec![ViewerPart { name: "prior", mesh: &old, rgb: prior_rgb }];
    match &by_confidence {
        Some(bins) => {
            for (k, mesh) in bins.iter().enumerate() {
                let rgb = confidence_rgb((k as f64 + 0.5) / CONFIDENCE_BINS as f64);
                parts.push(ViewerPart { name: &names[k], mesh, rgb });
            }
            html.push_str(&confidence_key("prior"));
        }
        None => parts.push(ViewerPart { name: "new vessels", mesh: &new, rgb: [60, 120, 220] }),
    }
    html.push_str(&viewer_html(&parts));
}

/// The colour key of the confidence pictures, after a grey entry named `context`.
fn confidence_key(context: &str) -> String {
    let mut key = format!("<p class=\"key\"><span style=\"background:#969696\">{context}</span>");
    for k in 0..CONFIDENCE_BINS {
        let [r, g, b] = confidence_rgb((k as f64 + 0.5) / CONFIDENCE_BINS as f64);
        let _ = write!(
            key,
            "<span style=\"background:#{r:02x}{g:02x}{b:02x}\">confidence {:.1}–{:.1}</span>",
            k as f64 / CONFIDENCE_BINS as f64,
            (k + 1) as f64 / CONFIDENCE_BINS as f64
        );
    }
    key.push_str("</p>");
    key
}

/// Scores of the completed surface and of the prior alone, when the case has ground truth.
fn metrics(html: &mut String, summary: &Value) {
    html.push_str("<h2>Metrics</h2>");
    if summary["metrics"].is_null() {
        html.push_str("<p>No ground truth in the case: no metrics.</p>");
        return;
    }
    html.push_str("<table><tr><th>surface</th><th>region</th><th>CD mean (mm)</th><th>CD sum (mm)</th><th>HD95 (mm)</th><th>HD (mm)</th></tr>");
    metrics_rows(html, "completed", &summary["metrics"]);
    if !summary["prior_metrics"].is_null() {
        metrics_rows(html, "prior alone", &summary["prior_metrics"]);
    }
    html.push_str("</table><p>Definitions: docs/METRICS.md (CD sum = the paper's convention); ∞: the surface has no point in that region.</p>");
    let t = &summary["topology"];
    if !t.is_null() {
        let _ = write!(
            html,
            "<table><tr><th>clDice</th><th>topology precision</th><th>topology sensitivity</th><th>components</th>\
             <th>true components</th><th>Betti-0 error</th></tr><tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td></tr></table>",
            num(&t["cl_dice"]),
            num(&t["topology_precision"]),
            num(&t["topology_sensitivity"]),
            text(&t["components"]),
            text(&t["true_components"]),
            text(&t["betti0_error"])
        );
    }
}

/// The centreline graph: lengths, scores against the true tree, and the found / missed picture.
fn centreline(html: &mut String, run_dir: &Path, summary: &Value) -> Result<()> {
    let c = &summary["centreline"];
    if c.is_null() {
        return Ok(());
    }
    let _ = write!(
        html,
        "<h2>Centreline</h2><p><code>centreline.swc</code> and <code>centreline.vtp</code> (3D Slicer, ParaView, VMTK):          {} nodes, {} mm in all, {} mm on new vessels (SWC type 4; type 3 = prior).</p>",
        text(&c["nodes"]),
        num(&c["length_mm"]),
        num(&c["new_length_mm"])
    );
    let s = &c["scores"];
    if !s.is_null() {
        let _ = write!(
            html,
            "<table><tr><th>missing length (mm)</th><th>recall</th><th>new length (mm)</th><th>precision</th>             <th>radius error (mm)</th><th>radius bias (mm)</th></tr><tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>             <p>Recall: share of the true missing vessels' centreline within their radius + 0.5 mm of the completed centreline;              precision: share of the new centreline that close to a true vessel (docs/METRICS.md).</p>",
            num(&s["missing_length_mm"]),
            num(&s["recall"]),
            num(&s["new_length_mm"]),
            num(&s["precision"]),
            num(&s["radius_error_mm"]),
            num(&s["radius_bias_mm"])
        );
    }
    let picture = run_dir.join("centreline.png");
    if picture.exists() {
        html.push_str(
            "<p class=\"key\"><span style=\"background:#28a046\">missing vessel found</span>              <span style=\"background:#eb8c14\">missing vessel missed</span>              <span style=\"background:#c828c8\">new branch on no true vessel</span>              <span style=\"background:#aaaaaa\">completed centreline</span></p>",
        );
        html.push_str(&png_tag(&picture, "true missing vessels found and missed, false new branches")?);
    }
    confidence(html, run_dir, c)
}

/// Which new branches to trust: the confidence picture and, with a true tree, the precision of
/// the new centreline per confidence bin.
fn confidence(html: &mut String, run_dir: &Path, centreline: &Value) -> Result<()> {
    let picture = run_dir.join("confidence.png");
    if !picture.exists() {
        return Ok(());
    }
    html.push_str(
        "<h3>Confidence of the new vessels</h3><p>Each new branch's confidence is the share of it that \
         the views show on their own (pixels no other branch covers), in the second-least supporting \
         view (docs/METRICS.md); per branch in <code>branches.csv</code>, per node in \
         <code>centreline.vtp</code> (<code>Confidence</code>), per vertex in <code>mesh-confidence.ply</code>.</p>",
    );
    html.push_str(&confidence_key("prior centreline"));
    html.push_str(&png_tag(&picture, "new branches coloured by confidence")?);
    if let Some(bins) = centreline["confidence_bins"].as_array() {
        html.push_str("<table><tr><th>confidence</th><th>new length (mm)</th><th>on a true vessel</th></tr>");
        for b in bins {
            let _ = write!(
                html,
                "<tr><td>{}–{}</td><td>{}</td><td>{}</td></tr>",
                num(&b["from"]),
                num(&b["to"]),
                num(&b["new_length_mm"]),
                num(&b["precision"])
            );
        }
        html.push_str("</table>");
    }
    Ok(())
}

/// Learned pose corrections (`poses.json`) and, for a synthetic case, their errors.
fn poses(html: &mut String, run_dir: &Path, summary: &Value) -> Result<()> {
    let poses_path = run_dir.join("poses.json");
    if !poses_path.exists() {
        return Ok(());
    }
    let poses: Value = serde_json::from_slice(&read_file(&poses_path)?)
        .map_err(|e| CoreError::format(&poses_path, format!("invalid poses: {e}")))?;
    html.push_str("<h2>Pose refinement</h2><table><tr><th>view</th><th>rotation (°, axis-angle)</th><th>translation (mm)</th></tr>");
    for v in poses["views"].as_array().into_iter().flatten() {
        let vec3 = |x: &Value| x.as_array().map_or("–".into(), |a| a.iter().map(num).collect::<Vec<_>>().join(", "));
        let _ = write!(
            html,
            "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(v["name"].as_str().unwrap_or("?")),
            vec3(&v["rotation_deg"]),
            vec3(&v["translation_mm"])
        );
    }
    html.push_str("</table>");
    if let Some(errors) = summary["pose_errors"].as_array() {
        html.push_str("<p>Against the known true poses:</p><table><tr><th>view</th><th>reprojection before (px)</th><th>after (px)</th><th>rotation error (°)</th><th>translation error (mm)</th></tr>");
        for e in errors {
            let _ = write!(
                html,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                text(&e["view"]),
                num(&e["reprojection_before_px"]),
                num(&e["reprojection_after_px"]),
                num(&e["rotation_error_deg"]),
                num(&e["translation_error_mm"])
            );
        }
        html.push_str("</table>");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A crafted run folder: markup in every value the page shows from summary.json and
    /// poses.json (numbers replaced by strings, arrays and objects) never reaches the page
    /// unescaped.
    #[test]
    fn markup_in_a_summary_is_escaped() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let evil = "<script>alert(1)</script><img src=x onerror=alert(2)>";
        let summary = serde_json::json!({
            "case_dir": evil,
            "iterations": evil,
            "gaussians": [evil],
            "n1": {"a": evil},
            "n2": evil,
            "mesh_triangles": evil,
            "metrics": {"overall": {"cd_mean_mm": evil, "cd_sum_mm": evil, "hd95_mm": evil, "hd_mm": evil}},
            "centreline": {"nodes": evil, "length_mm": evil, "new_length_mm": evil, "scores": {"recall": evil}},
            "pose_errors": [{"view": evil, "reprojection_before_px": evil}],
            "arrival_readings": [{"view": evil, "noise": evil, "median_px": evil}],
            "view_readings": [{"view": evil, "noise_sigma": evil, "bright": evil, "reading": evil}],
            "topology": {"cl_dice": evil, "components": evil, "true_components": [evil], "betti0_error": {"x": evil}},
            "ensemble_runs": [evil, {"x": evil}],
        });
        std::fs::write(dir.join("summary.json"), summary.to_string()).unwrap();
        let poses = serde_json::json!({"views": [{"name": evil, "rotation_deg": [evil], "translation_mm": evil}]});
        std::fs::write(dir.join("poses.json"), poses.to_string()).unwrap();
        std::fs::write(dir.join("config.toml"), evil).unwrap();
        let page = std::fs::read_to_string(write_report(&dir).unwrap().path).unwrap();
        assert!(!page.contains("<script>alert"), "unescaped script");
        assert!(!page.contains("<img src=x"), "unescaped element");
        assert!(page.contains("&lt;script&gt;alert(1)"), "the value is shown, escaped");
        // The page's own scripts: only the one that counts decoded images.
        assert_eq!(page.matches("<script").count(), 1, "one script of the page's own");
    }

    /// Each view's arrival map reading appears with its noise in percent and the median it got.
    #[test]
    fn arrival_readings_are_shown_per_view() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let summary = serde_json::json!({
            "arrival_readings": [{"view": "ap", "noise": 0.018, "median_px": 0}, {"view": "lat", "noise": 0.3125, "median_px": 1}],
        });
        std::fs::write(dir.join("summary.json"), summary.to_string()).unwrap();
        let page = std::fs::read_to_string(write_report(&dir).unwrap().path).unwrap();
        assert!(page.contains("<tr><td>ap</td><td>1.8 %</td><td>as it is</td></tr>"), "{page}");
        assert!(page.contains("<tr><td>lat</td><td>31.2 %</td><td>through a 3 × 3 median</td></tr>"), "{page}");
    }

    /// Each view's noise reading appears with its σ, bright value, their ratio and how it was read.
    #[test]
    fn view_readings_are_shown_per_view() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        let summary = serde_json::json!({
            "view_readings": [
                {"view": "ap", "noise_sigma": 0.2, "bright": 8.0, "reading": "under_floor_along_lines"},
                {"view": "lat", "noise_sigma": 0.0, "bright": 12.5, "reading": "per_pixel"},
                {"view": "oblique", "noise_sigma": 0.1, "bright": 9.0, "reading": "along_lines"},
            ],
        });
        std::fs::write(dir.join("summary.json"), summary.to_string()).unwrap();
        let page = std::fs::read_to_string(write_report(&dir).unwrap().path).unwrap();
        assert!(
            page.contains(
                "<tr><td>ap</td><td>0.2000</td><td>8.0000</td><td>2.5 %</td><td>under 3 σ along lines</td></tr>"
            ),
            "{page}"
        );
        assert!(
            page.contains("<tr><td>lat</td><td>0.0000</td><td>12.5000</td><td>0.0 %</td><td>per pixel</td></tr>"),
            "{page}"
        );
        assert!(
            page.contains("<tr><td>oblique</td><td>0.1000</td><td>9.0000</td><td>1.1 %</td><td>along lines</td></tr>"),
            "{page}"
        );
    }

    /// A file the page would show that is present but unreadable (a damaged mesh) is named at
    /// the top of the page and in `left_out`, instead of its part silently missing.
    #[test]
    fn unreadable_parts_are_named_not_silently_dropped() {
        let temp = tempfile::tempdir().unwrap();
        let dir = temp.path().to_path_buf();
        std::fs::write(dir.join("summary.json"), serde_json::json!({"iterations": 3}).to_string()).unwrap();
        std::fs::write(dir.join("mesh.obj"), "v 1 2\nf 1 2 3\n").unwrap();
        let written = write_report(&dir).unwrap();
        assert_eq!(written.left_out.len(), 1, "{:?}", written.left_out);
        assert!(written.left_out[0].contains("mesh.obj"), "{:?}", written.left_out);
        let page = std::fs::read_to_string(&written.path).unwrap();
        assert!(page.contains("Left out of this page") && page.contains("mesh.obj"));
        // A folder without a summary (a run still going, a case folder) and a missing folder.
        std::fs::remove_file(dir.join("summary.json")).unwrap();
        let err = write_report(&dir).unwrap_err().to_string();
        assert!(err.contains("is not a finished run folder") && err.contains(dir.to_str().unwrap()), "{err}");
        let err = write_report(&dir.join("nowhere")).unwrap_err().to_string();
        assert!(err.contains("does not exist") && err.contains("nowhere"), "{err}");
    }
}
