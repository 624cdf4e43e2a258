//! `report/scene.js`: the viewer's data (points, cameras, the decimated mesh with its JPEG atlas
//! as a data URI, the scene's centre and size) as one JavaScript assignment, `window.HANDHELD =
//! {…};`. A `<script src>` loads it, since browsers block `fetch` of local files. The JSON is
//! escaped for JavaScript ([`js_json`]): camera names are file names, and none can end the script.

use std::path::Path;

use crate::encode::{b64, jpeg};
use crate::html::js_json;
use crate::input::{ReportInput, Result};

pub(crate) fn scene_js(
    input: &ReportInput,
    thumbs: &[Option<String>],
    path: &Path,
) -> Result<String> {
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
    Ok(format!("window.HANDHELD = {};\n", js_json(&scene)))
}
