//! The workspace report: `report.html`, a quality report a person opens by double-click. It works
//! from `file://` with no server and no network: the page, its inline SVG plots and its viewer
//! are in the HTML; the 3D data (points, cameras, the decimated mesh with its JPEG atlas as a
//! data URI) are in `report/scene.js` beside it, loaded by a `<script>` tag (browsers block
//! `fetch` of local files, not scripts); thumbnails are `report/thumbs/*.jpg`. Nothing comes from
//! elsewhere, so the workspace folder can be zipped and mailed.
//!
//! This crate only formats: the pipeline gathers what the stages left into a [`ReportInput`].
//!
//! Where each piece lives: `lib.rs` writes `report.html` (the verdict, the image grid and the renders) and
//! `report/scene.js` (base64 points, cameras, mesh, JPEG atlas as a data URI); [`svg`] draws the inline SVG plots
//! (histogram, bar chart, matrix, camera path); `viewer.js` is the hand-written WebGL2 viewer, inlined into the page.
//! No file is read here.

pub mod svg;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use base64::Engine;
use handheld_core::TriMesh;
use image::RgbImage;
use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum ReportError {
    #[error("{path}: cannot encode ({reason})")]
    Encode { path: PathBuf, reason: String },
}

pub type Result<T> = std::result::Result<T, ReportError>;

/// The verdict at the top.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Verdict {
    pub images_in: usize,
    pub registered: Option<usize>,
    /// e.g. "pinhole + radial k1, one camera".
    pub camera_model: Option<String>,
    /// Focal length and its standard deviation (pixels).
    pub focal_px: Option<f64>,
    pub focal_sigma_px: Option<f64>,
    pub reprojection_px: Option<f64>,
    pub total_seconds: f64,
}

/// One input image.
#[derive(Clone, Debug, Default)]
pub struct ImageEntry {
    pub name: String,
    pub thumb: Option<RgbImage>,
    pub registered: Option<bool>,
    /// Why it was not registered.
    pub reason: Option<String>,
    pub observations: Option<usize>,
    /// Relative to the workspace: the dense stage's depth preview, and its fill.
    pub depth_preview: Option<String>,
    pub fill: Option<f64>,
}

/// One recorded camera for the viewer.
#[derive(Clone, Debug, Serialize)]
pub struct ViewerCamera {
    pub name: String,
    /// Centre, and world ← camera rotation (row-major).
    pub c: [f64; 3],
    pub r: [f64; 9],
    pub f: f64,
    pub aspect: f64,
    pub cx: f64,
    pub cy: f64,
    pub w: u32,
    pub h: u32,
    pub registered: bool,
    /// The thumbnail, relative to the page.
    pub thumb: String,
}

/// A stage's warning: what happened in plain language, what to do, and the figures behind it
/// (folded away on the page). `code` is the stable kind (`focal_undetermined`, ...).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ReportWarning {
    pub code: String,
    pub text: String,
    pub advice: Option<String>,
    pub details: Option<String>,
}

impl From<&str> for ReportWarning {
    fn from(text: &str) -> Self {
        Self {
            code: "note".into(),
            text: text.into(),
            ..Default::default()
        }
    }
}

/// Everything the report shows.
#[derive(Clone, Debug, Default)]
pub struct ReportInput {
    pub title: String,
    pub verdict: Verdict,
    /// Warnings in words a user understands, with what to do.
    pub warnings: Vec<ReportWarning>,
    /// Stages that have not run (the report says what is missing).
    pub missing: Vec<String>,
    pub images: Vec<ImageEntry>,
    pub reprojection_errors: Vec<f64>,
    pub track_lengths: Vec<usize>,
    /// Image count and (i, j, inliers) of the verified pairs.
    pub pairs: Option<(usize, Vec<(usize, usize, f64)>)>,
    /// Index into `images` of each camera.
    pub cameras: Vec<(usize, ViewerCamera)>,
    pub up: [f64; 3],
    pub stage_times: Vec<(String, f64)>,
    pub points: Vec<([f32; 3], [u8; 3])>,
    pub mesh: Option<(TriMesh, Option<RgbImage>)>,
    /// (label, path relative to the workspace) of renders: PNG images and MP4 videos.
    pub renders: Vec<(String, String)>,
}

/// What was written.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReportSummary {
    pub html: PathBuf,
    pub bytes: u64,
    pub points: usize,
    pub mesh_faces: usize,
    pub cameras: usize,
    pub images: usize,
    pub missing: Vec<String>,
}

/// `report/` beside `report.html`.
pub const REPORT_DIR: &str = "report";
pub const REPORT_HTML: &str = "report.html";

fn jpeg(img: &RgbImage, quality: u8, path: &Path) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality)
        .encode_image(img)
        .map_err(|e| ReportError::Encode {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    Ok(out)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The report's files, relative to the workspace, and what they hold. The caller writes them
/// (this crate touches no file).
pub struct ReportFiles {
    pub files: Vec<(PathBuf, Vec<u8>)>,
    pub summary: ReportSummary,
}

/// Formats the report: `report.html`, `report/scene.js` and `report/thumbs/*.jpg`.
pub fn render_report(input: &ReportInput) -> Result<ReportFiles> {
    let mut files = Vec::new();
    let mut thumb_paths = Vec::new();
    for (k, im) in input.images.iter().enumerate() {
        match &im.thumb {
            Some(t) => {
                let rel = format!("{REPORT_DIR}/thumbs/{k:05}.jpg");
                files.push((PathBuf::from(&rel), jpeg(t, 80, Path::new(&rel))?));
                thumb_paths.push(Some(rel));
            }
            None => thumb_paths.push(None),
        }
    }
    let scene_rel = PathBuf::from(format!("{REPORT_DIR}/scene.js"));
    let scene = scene_js(input, &thumb_paths, &scene_rel)?;
    files.push((scene_rel, scene.into_bytes()));
    // The page last: it is what a person opens, so it appears only once the rest is there.
    files.push((
        PathBuf::from(REPORT_HTML),
        page(input, &thumb_paths).into_bytes(),
    ));
    let bytes = files.iter().map(|f| f.1.len() as u64).sum();
    Ok(ReportFiles {
        files,
        summary: ReportSummary {
            html: PathBuf::from(REPORT_HTML),
            bytes,
            points: input.points.len(),
            mesh_faces: input.mesh.as_ref().map_or(0, |m| m.0.faces.len()),
            cameras: input.cameras.len(),
            images: input.images.len(),
            missing: input.missing.clone(),
        },
    })
}

fn scene_js(input: &ReportInput, thumbs: &[Option<String>], path: &Path) -> Result<String> {
    let pos: Vec<u8> = input
        .points
        .iter()
        .flat_map(|p| p.0.iter().flat_map(|v| v.to_le_bytes()))
        .collect();
    let col: Vec<u8> = input.points.iter().flat_map(|p| p.1).collect();
    // The scene's centre and size: medians of the points (or the cameras).
    let sample: Vec<[f64; 3]> = if input.points.is_empty() {
        input.cameras.iter().map(|c| c.1.c).collect()
    } else {
        input.points.iter().map(|p| p.0.map(f64::from)).collect()
    };
    let med = |k: usize| {
        let mut v: Vec<f64> = sample.iter().map(|p| p[k]).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let center = [med(0), med(1), med(2)];
    let mut d: Vec<f64> = sample
        .iter()
        .map(|p| {
            ((p[0] - center[0]).powi(2) + (p[1] - center[1]).powi(2) + (p[2] - center[2]).powi(2))
                .sqrt()
        })
        .collect();
    d.sort_by(f64::total_cmp);
    let mut radius = d.get(d.len() * 8 / 10).copied().unwrap_or(1.0).max(1e-9);
    // Far, sparse outliers must not set the scale: at most the cameras' median distance.
    let mut cd: Vec<f64> = input
        .cameras
        .iter()
        .map(|c| {
            ((c.1.c[0] - center[0]).powi(2)
                + (c.1.c[1] - center[1]).powi(2)
                + (c.1.c[2] - center[2]).powi(2))
            .sqrt()
        })
        .collect();
    cd.sort_by(f64::total_cmp);
    if let Some(&m) = cd.get(cd.len() / 2) {
        if m > 0.0 {
            radius = radius.min(m);
        }
    }
    let cameras: Vec<serde_json::Value> = input
        .cameras
        .iter()
        .map(|(k, c)| {
            let mut v = serde_json::to_value(c).unwrap_or_default();
            v["thumb"] = serde_json::json!(thumbs.get(*k).cloned().flatten().unwrap_or_default());
            v
        })
        .collect();
    let mesh = match &input.mesh {
        Some((m, tex)) if !m.faces.is_empty() => {
            let p: Vec<u8> = m
                .vertices
                .positions
                .iter()
                .flat_map(|v| v.iter().flat_map(|x| x.to_le_bytes()))
                .collect();
            let uv: Vec<u8> = if m.uvs.len() == m.vertices.positions.len() {
                m.uvs
                    .iter()
                    .flat_map(|t| t.iter().flat_map(|x| x.to_le_bytes()))
                    .collect()
            } else {
                vec![0u8; m.vertices.positions.len() * 8]
            };
            let idx: Vec<u8> = m
                .faces
                .iter()
                .flat_map(|f| f.iter().flat_map(|i| i.to_le_bytes()))
                .collect();
            let atlas = match tex {
                Some(t) => Some(format!(
                    "data:image/jpeg;base64,{}",
                    b64(&jpeg(t, 85, path)?)
                )),
                None => None,
            };
            serde_json::json!({"faces": m.faces.len(), "pos": b64(&p), "uv": b64(&uv), "idx": b64(&idx), "atlas": atlas})
        }
        _ => serde_json::Value::Null,
    };
    let scene = serde_json::json!({
        "points": {"count": input.points.len(), "pos": b64(&pos), "col": b64(&col)},
        "cameras": cameras,
        "mesh": mesh,
        "center": center,
        "radius": radius,
        "up": input.up,
        "frustum_depth": radius * 0.12,
    });
    Ok(format!("window.HANDHELD = {scene};\n"))
}

const STYLE: &str = r#"
body{font:14px/1.45 system-ui,sans-serif;margin:0;color:#1d1f23;background:#f4f5f7}
header{background:#1d2530;color:#fff;padding:16px 28px}header h1{margin:0;font-size:20px}
main{padding:8px 28px 40px;max-width:1400px}section{margin:22px 0}h2{font-size:17px;border-bottom:1px solid #ccd;padding-bottom:4px}
.verdict{display:flex;flex-wrap:wrap;gap:10px}.kv{background:#fff;border:1px solid #dde;border-radius:6px;padding:8px 14px;min-width:150px}
.kv b{display:block;font-size:18px}.warn{background:#fff4e0;border-left:4px solid #e69500;padding:8px 12px;margin:6px 0}
.ok{background:#e8f6ea;border-left:4px solid #2e9d49;padding:8px 12px}.missing{color:#777}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(170px,1fr));gap:10px}
.img{background:#fff;border:1px solid #dde;border-radius:6px;padding:6px;font-size:12px}.img img{width:100%;display:block}
.img.bad{border-color:#d33;background:#fff0f0}.tag{display:inline-block;padding:0 6px;border-radius:3px;color:#fff;background:#2e9d49}
.img.bad .tag{background:#c22}.plots{display:flex;flex-wrap:wrap;gap:12px}.plot{background:#fff;border:1px solid #dde;border-radius:6px}
.plot .t{font-size:13px;font-weight:600}.plot .l,.plot .k{font-size:10px;fill:#555}.plot .a{stroke:#888}.plot .b{fill:#4a78c2}
.plot .bg{fill:#f7f8fa}.plot .p{fill:none;stroke:#4a78c2;stroke-width:1.2}.plot .c{fill:#e8741a}.plot .c0{fill:#2e9d49}.plot .pt{fill:#999}
#hh-view{display:flex;gap:12px;align-items:flex-start}#hh-canvas{width:960px;height:540px;background:#222;border-radius:6px;cursor:grab}
#hh-side{width:260px}#hh-photo img{width:100%}#hh-status{font-size:11px;color:#666;white-space:pre-wrap;word-break:break-all}
video,.render img{max-width:100%}
body.viewer-only header,body.viewer-only main>section:not(#hh-viewer){display:none}
body.viewer-only main{padding:0;max-width:none}body.viewer-only #hh-viewer{margin:0}body.viewer-only h2{display:none}
body.viewer-only #hh-canvas{width:1280px;height:720px;border-radius:0}body.viewer-only #hh-side{display:none}
"#;

fn page(input: &ReportInput, thumbs: &[Option<String>]) -> String {
    let v = &input.verdict;
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body><header><h1>{t}</h1></header><main>",
        t = esc(&input.title)
    );
    // Verdict.
    h.push_str("<section><h2>Verdict</h2><div class=\"verdict\">");
    let kv = |h: &mut String, k: &str, v: String| {
        let _ = write!(h, "<div class=\"kv\">{}<b>{}</b></div>", esc(k), esc(&v));
    };
    kv(
        &mut h,
        "images registered",
        match v.registered {
            Some(r) => format!("{r} / {}", v.images_in),
            None => format!("— / {}", v.images_in),
        },
    );
    kv(
        &mut h,
        "camera model",
        v.camera_model.clone().unwrap_or_else(|| "—".into()),
    );
    kv(
        &mut h,
        "focal length",
        match (v.focal_px, v.focal_sigma_px) {
            (Some(f), Some(s)) => format!("{f:.1} px ± {s:.2}"),
            (Some(f), None) => format!("{f:.1} px"),
            _ => "—".into(),
        },
    );
    kv(
        &mut h,
        "reprojection error",
        v.reprojection_px
            .map_or("—".into(), |r| format!("{r:.3} px")),
    );
    kv(&mut h, "total time", format!("{:.1} s", v.total_seconds));
    h.push_str("</div>");
    if input.warnings.is_empty() {
        h.push_str("<div class=\"ok\">No warnings.</div>");
    }
    for w in &input.warnings {
        let _ = write!(
            h,
            "<div class=\"warn\" data-code=\"{}\">{}",
            esc(&w.code),
            esc(&w.text)
        );
        if let Some(a) = &w.advice {
            let _ = write!(h, "<br><b>What to do:</b> {}", esc(a));
        }
        if let Some(d) = &w.details {
            let _ = write!(h, "<details><summary>details</summary>{}</details>", esc(d));
        }
        h.push_str("</div>");
    }
    for m in &input.missing {
        let _ = write!(h, "<div class=\"missing\">Not run yet: {}</div>", esc(m));
    }
    h.push_str("</section>");
    // Images.
    let _ = write!(
        h,
        "<section><h2>Images ({})</h2><div class=\"grid\">",
        input.images.len()
    );
    for (k, im) in input.images.iter().enumerate() {
        let bad = im.registered == Some(false);
        let _ = write!(h, "<div class=\"img{}\">", if bad { " bad" } else { "" });
        if let Some(t) = &thumbs[k] {
            let _ = write!(h, "<img src=\"{t}\" alt=\"\" loading=\"lazy\">");
        }
        let _ = write!(h, "<div>{}</div>", esc(&im.name));
        match im.registered {
            Some(true) => {
                let _ = write!(
                    h,
                    "<span class=\"tag\">registered</span> {} observations",
                    im.observations.unwrap_or(0)
                );
            }
            Some(false) => {
                let _ = write!(
                    h,
                    "<span class=\"tag\">not registered</span> {}",
                    esc(im.reason.as_deref().unwrap_or("no reason recorded"))
                );
            }
            None => h.push_str("<span class=\"missing\">not reconstructed yet</span>"),
        }
        if let Some(d) = &im.depth_preview {
            let _ = write!(
                h,
                "<img src=\"{}\" alt=\"depth\" loading=\"lazy\"><div>depth fill {:.0} %</div>",
                esc(d),
                im.fill.unwrap_or(0.0) * 100.0
            );
        }
        h.push_str("</div>");
    }
    h.push_str("</div></section>");
    // Plots.
    h.push_str("<section><h2>Plots</h2><div class=\"plots\">");
    if !input.reprojection_errors.is_empty() {
        let mut e = input.reprojection_errors.clone();
        e.sort_by(f64::total_cmp);
        let hi = e[(e.len() * 99 / 100).min(e.len() - 1)].max(1e-3);
        h.push_str(&svg::histogram(
            "Reprojection errors",
            "pixels",
            &e,
            0.0,
            hi,
            30,
        ));
    }
    if !input.track_lengths.is_empty() {
        let l: Vec<f64> = input.track_lengths.iter().map(|v| *v as f64).collect();
        let hi = l.iter().fold(2.0f64, |a, b| a.max(*b)) + 1.0;
        let bins = (hi as usize).clamp(2, 40);
        h.push_str(&svg::histogram(
            "Track lengths",
            "views per point",
            &l,
            0.0,
            hi,
            bins,
        ));
    }
    if let Some((n, cells)) = &input.pairs {
        h.push_str(&svg::matrix("Verified pairs (inliers)", *n, cells));
    }
    if !input.cameras.is_empty() {
        let up = input.up;
        let (a, b) = basis(&up);
        let cs: Vec<[f64; 3]> = input.cameras.iter().map(|c| c.1.c).collect();
        let pts: Vec<[f64; 3]> = input
            .points
            .iter()
            .step_by((input.points.len() / 3000).max(1))
            .map(|p| p.0.map(f64::from))
            .collect();
        let dot = |p: &[f64; 3], q: &[f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
        // Points within the cameras' box widened by its size (plus the scene's median depth), so
        // far outliers do not squash the path.
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &cs {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let mut dists: Vec<f64> = pts
            .iter()
            .map(|p| {
                cs.iter()
                    .map(|c| {
                        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2))
                            .sqrt()
                    })
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        dists.sort_by(f64::total_cmp);
        let reach = dists.get(dists.len() / 2).copied().unwrap_or(0.0) * 1.5;
        let near: Vec<[f64; 3]> = pts
            .iter()
            .filter(|p| {
                (0..3).all(|k| {
                    p[k] >= lo[k] - reach - (hi[k] - lo[k])
                        && p[k] <= hi[k] + reach + (hi[k] - lo[k])
                })
            })
            .copied()
            .collect();
        let top: Vec<[f64; 2]> = cs.iter().map(|p| [dot(p, &a), dot(p, &b)]).collect();
        let topp: Vec<[f64; 2]> = near.iter().map(|p| [dot(p, &a), dot(p, &b)]).collect();
        let side: Vec<[f64; 2]> = cs.iter().map(|p| [dot(p, &a), dot(p, &up)]).collect();
        let sidep: Vec<[f64; 2]> = near.iter().map(|p| [dot(p, &a), dot(p, &up)]).collect();
        h.push_str(&svg::path(
            "Camera path from above",
            "green: first camera; grey: points",
            &top,
            &topp,
        ));
        h.push_str(&svg::path(
            "Camera path from the side",
            "up is up",
            &side,
            &sidep,
        ));
    }
    if !input.stage_times.is_empty() {
        h.push_str(&svg::bar_chart(
            "Time per stage",
            "seconds",
            &input.stage_times,
        ));
    }
    h.push_str("</div></section>");
    // Viewer.
    h.push_str(
        "<section id=\"hh-viewer\"><h2>3D viewer</h2><div id=\"hh-view\"><canvas id=\"hh-canvas\"></canvas><div id=\"hh-side\">\
         <div><label><input type=\"checkbox\" id=\"hh-layer-mesh\" checked> mesh</label> \
         <label><input type=\"checkbox\" id=\"hh-layer-points\" checked> points</label> \
         <label><input type=\"checkbox\" id=\"hh-layer-cameras\" checked> cameras</label> \
         <button id=\"hh-reset\">reset view</button></div>\
         <p>Drag to orbit, shift-drag or right-drag to pan, wheel to zoom. Click a camera to see its photo and look through it. <a href=\"#viewer\" onclick=\"setTimeout(()=>location.reload())\">Viewer only</a> (1280×720).</p>\
         <div id=\"hh-photo\"></div><pre id=\"hh-status\"></pre></div></div></section>",
    );
    // Renders.
    if !input.renders.is_empty() {
        h.push_str("<section><h2>Renders</h2>");
        for (label, path) in &input.renders {
            let _ = write!(h, "<div class=\"render\"><h3>{}</h3>", esc(label));
            if path.ends_with(".mp4") {
                let _ = write!(
                    h,
                    "<video src=\"{}\" controls loop muted></video>",
                    esc(path)
                );
            } else {
                let _ = write!(h, "<img src=\"{}\" alt=\"\">", esc(path));
            }
            h.push_str("</div>");
        }
        h.push_str("</section>");
    }
    let _ = write!(
        h,
        "</main><script src=\"{REPORT_DIR}/scene.js\"></script><script>{}</script></body></html>",
        include_str!("viewer.js")
    );
    h
}

/// Two unit vectors orthogonal to `up` and to each other.
fn basis(up: &[f64; 3]) -> ([f64; 3], [f64; 3]) {
    let a0 = if up[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let d = a0[0] * up[0] + a0[1] * up[1] + a0[2] * up[2];
    let mut a = [a0[0] - d * up[0], a0[1] - d * up[1], a0[2] - d * up[2]];
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt().max(1e-12);
    a = a.map(|v| v / n);
    let b = [
        up[1] * a[2] - up[2] * a[1],
        up[2] * a[0] - up[0] * a[2],
        up[0] * a[1] - up[1] * a[0],
    ];
    (a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A failed image shows with its reason, a warning and a missing stage show in the verdict,
    /// and every file is inside `report/` or the page itself.
    #[test]
    fn failed_images_warnings_and_missing_stages_are_shown() {
        let input = ReportInput {
            title: "t".into(),
            verdict: Verdict {
                images_in: 2,
                registered: Some(1),
                ..Default::default()
            },
            warnings: vec!["sparse: critical motion <give --intrinsics>".into()],
            missing: vec!["mesh".into()],
            images: vec![
                ImageEntry {
                    name: "a.jpg".into(),
                    thumb: Some(RgbImage::new(8, 6)),
                    registered: Some(true),
                    observations: Some(10),
                    ..Default::default()
                },
                ImageEntry {
                    name: "b.jpg".into(),
                    registered: Some(false),
                    reason: Some("too few matches".into()),
                    ..Default::default()
                },
            ],
            reprojection_errors: vec![0.1, 0.2, 0.3],
            track_lengths: vec![2, 3, 3],
            ..Default::default()
        };
        let out = render_report(&input).unwrap();
        let html = String::from_utf8(out.files.last().unwrap().1.clone()).unwrap();
        assert!(html.contains("too few matches") && html.contains("not registered"));
        assert!(html.contains("critical motion &lt;give --intrinsics&gt;"));
        assert!(html.contains("Not run yet: mesh"));
        assert!(html.contains("<svg") && html.contains("Reprojection errors"));
        for (p, _) in &out.files {
            assert!(
                p == Path::new(REPORT_HTML) || p.starts_with(REPORT_DIR),
                "{}",
                p.display()
            );
        }
        assert_eq!(out.summary.images, 2);
    }
}
