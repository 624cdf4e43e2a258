//! `report.html`: the verdict, the images, the plots (inline SVG), the 3D viewer's frame and
//! the renders, in that order. Every string from data is escaped here ([`esc`], [`url_path`]);
//! the viewer (inline, `viewer.js`) builds its text with `textContent`. The page carries a
//! Content-Security-Policy ([`content_security_policy`]) that allows no network, no inline
//! event handler, and of inline code only the stylesheet and the viewer, by their hashes.

use std::fmt::Write as _;

use crate::html::{content_security_policy, esc, url_path};
use crate::input::{ReportInput, REPORT_DIR};
use crate::svg;

/// The viewer's script, inline in the page (allowed by its hash).
pub(crate) const VIEWER_JS: &str = include_str!("viewer.js");

const STYLE: &str = r#"
body{font:14px/1.45 system-ui,sans-serif;margin:0;color:#1d1f23;background:#f4f5f7}
header{background:#1d2530;color:#fff;padding:16px 28px}header h1{margin:0;font-size:20px}
main{padding:8px 28px 40px;max-width:1400px}section{margin:22px 0}h2{font-size:17px;border-bottom:1px solid #ccd;padding-bottom:4px}
.verdict{display:flex;flex-wrap:wrap;gap:10px}.kv{background:#fff;border:1px solid #dde;border-radius:6px;padding:8px 14px;min-width:150px}
.kv b{display:block;font-size:18px}.warn{background:#fff4e0;border-left:4px solid #e69500;padding:8px 12px;margin:6px 0}
.ok{background:#e8f6ea;border-left:4px solid #2e9d49;padding:8px 12px}.missing{color:#777}.note{color:#8a5a00}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(170px,1fr));gap:10px}
.img{background:#fff;border:1px solid #dde;border-radius:6px;padding:6px;font-size:12px}.img img{width:100%;display:block}
.img>div,#hh-photo div{overflow-wrap:anywhere}.img.bad{border-color:#d33;background:#fff0f0}.tag{display:inline-block;padding:0 6px;border-radius:3px;color:#fff;background:#2e9d49}
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

/// The whole page; `thumbs[k]` is image k's thumbnail, relative to the page.
pub(crate) fn page(input: &ReportInput, thumbs: &[Option<String>]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta http-equiv=\"Content-Security-Policy\" content=\"{csp}\">\
         <title>{t}</title><style>{STYLE}</style></head><body><header><h1>{t}</h1></header><main>",
        // Our own text (keywords and base64 hashes), with no `"` or `&`: as it is.
        csp = content_security_policy(STYLE, VIEWER_JS),
        t = esc(&input.title)
    );
    verdict(&mut h, input);
    images(&mut h, input, thumbs);
    h.push_str("<section><h2>Plots</h2><div class=\"plots\">");
    plots(&mut h, input);
    h.push_str("</div></section>");
    viewer(&mut h);
    renders(&mut h, input);
    let _ = write!(
        h,
        "</main><script src=\"{REPORT_DIR}/scene.js\"></script><script>{VIEWER_JS}</script></body></html>"
    );
    h
}

/// The verdict: registered images, camera model, focal length, reprojection error and time;
/// then the warnings and the stages not run yet.
fn verdict(h: &mut String, input: &ReportInput) {
    let v = &input.verdict;
    h.push_str("<section><h2>Verdict</h2><div class=\"verdict\">");
    let kv = |h: &mut String, k: &str, v: String| {
        let _ = write!(h, "<div class=\"kv\">{}<b>{}</b></div>", esc(k), esc(&v));
    };
    kv(
        h,
        "images registered",
        match v.registered {
            Some(r) => format!("{r} / {}", v.images_in),
            None => format!("— / {}", v.images_in),
        },
    );
    kv(
        h,
        "camera model",
        v.camera_model.clone().unwrap_or_else(|| "—".into()),
    );
    kv(
        h,
        "focal length",
        match (v.focal_px, v.focal_sigma_px) {
            (Some(f), Some(s)) => format!("{f:.1} px ± {s:.2}"),
            (Some(f), None) => format!("{f:.1} px"),
            _ => "—".into(),
        },
    );
    if let Some(m) = &v.metric_frame {
        kv(h, "metric frame from", m.clone());
    }
    kv(
        h,
        "reprojection error",
        v.reprojection_px
            .map_or("—".into(), |r| format!("{r:.3} px")),
    );
    kv(h, "total time", format!("{:.1} s", v.total_seconds));
    h.push_str("</div>");
    if input.warnings.is_empty() {
        h.push_str("<div class=\"ok\">No warnings.</div>");
    }
    for w in &input.warnings {
        // A code is an identifier (`focal_undetermined`): anything else is dropped from it.
        let code: String = w
            .code
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        let _ = write!(
            h,
            "<div class=\"warn\" data-code=\"{code}\">{}",
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
}

/// The grid of images: thumbnail, name, registered or why not, depth preview and fill.
fn images(h: &mut String, input: &ReportInput, thumbs: &[Option<String>]) {
    let _ = write!(
        h,
        "<section><h2>Images ({})</h2><div class=\"grid\">",
        input.images.len()
    );
    for (k, im) in input.images.iter().enumerate() {
        let bad = im.registered == Some(false);
        let _ = write!(h, "<div class=\"img{}\">", if bad { " bad" } else { "" });
        if let Some(Some(t)) = thumbs.get(k) {
            let _ = write!(h, "<img src=\"{}\" alt=\"\" loading=\"lazy\">", url_path(t));
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
        if let Some(n) = &im.note {
            let _ = write!(h, "<div class=\"note\">{}</div>", esc(n));
        }
        if let Some(d) = &im.depth_preview {
            let _ = write!(
                h,
                "<img src=\"{}\" alt=\"depth\" loading=\"lazy\"><div>depth fill {:.0} %</div>",
                url_path(d),
                im.fill.unwrap_or(0.0) * 100.0
            );
        }
        h.push_str("</div>");
    }
    h.push_str("</div></section>");
}

/// The plots: reprojection errors, track lengths, the pair matrix, the camera path and the
/// time per stage, each when there is data for it.
fn plots(h: &mut String, input: &ReportInput) {
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
    camera_path(h, input);
    if !input.stage_times.is_empty() {
        h.push_str(&svg::bar_chart(
            "Time per stage",
            "seconds",
            &input.stage_times,
        ));
    }
}

/// The camera path seen from above and from the side, with the points near the cameras.
fn camera_path(h: &mut String, input: &ReportInput) {
    if input.cameras.is_empty() {
        return;
    }
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
                    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
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
                p[k] >= lo[k] - reach - (hi[k] - lo[k]) && p[k] <= hi[k] + reach + (hi[k] - lo[k])
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

/// The viewer's frame: the canvas, the layer toggles, the photo panel and the status line
/// that `viewer.js` fills (the browser test reads it).
fn viewer(h: &mut String) {
    h.push_str(
        "<section id=\"hh-viewer\"><h2>3D viewer</h2><div id=\"hh-view\"><canvas id=\"hh-canvas\"></canvas><div id=\"hh-side\">\
         <div><label><input type=\"checkbox\" id=\"hh-layer-mesh\" checked> mesh</label> \
         <label><input type=\"checkbox\" id=\"hh-layer-points\" checked> points</label> \
         <label><input type=\"checkbox\" id=\"hh-layer-cameras\" checked> cameras</label> \
         <button id=\"hh-reset\">reset view</button></div>\
         <p>Drag to orbit, shift-drag or right-drag to pan, wheel to zoom. Click a camera to see its photo and look through it. <a href=\"#viewer\" id=\"hh-viewer-only\">Viewer only</a> (1280×720).</p>\
         <div id=\"hh-photo\"></div><pre id=\"hh-status\"></pre></div></div></section>",
    );
}

/// The renders: PNG images and MP4 videos, each under its label.
fn renders(h: &mut String, input: &ReportInput) {
    if input.renders.is_empty() {
        return;
    }
    h.push_str("<section><h2>Renders</h2>");
    for (label, path) in &input.renders {
        let _ = write!(h, "<div class=\"render\"><h3>{}</h3>", esc(label));
        if path.ends_with(".mp4") {
            let _ = write!(
                h,
                "<video src=\"{}\" controls loop muted></video>",
                url_path(path)
            );
        } else {
            let _ = write!(h, "<img src=\"{}\" alt=\"\">", url_path(path));
        }
        h.push_str("</div>");
    }
    h.push_str("</section>");
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
