//! The report in a real browser: Debian's Chromium, headless, software WebGL (SwiftShader), the
//! network blocked. Skipped with a message when Chromium is missing (CI installs it).

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::Command;

fn chromium() -> Option<PathBuf> {
    let p = std::env::var_os("HANDHELD_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("chromium"));
    let ok = Command::new(&p)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        Some(p)
    } else {
        assert!(
            std::env::var_os("CI").is_none(),
            "chromium must be installed on CI"
        );
        eprintln!("chromium not installed: skipping the browser test (apt-get install chromium)");
        None
    }
}

fn browser(chrome: &Path, profile: &Path, extra: &[&str], url: &str) -> std::process::Output {
    Command::new(chrome)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-default-apps",
            "--disable-domain-reliability",
            "--disable-client-side-phishing-detection",
            "--no-pings",
            "--disable-features=NetworkTimeServiceQuerying,OptimizationHints,MediaRouter,Translate",
            "--host-resolver-rules=MAP * ~NOTFOUND",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(url)
        .output()
        .expect("chromium runs")
}

/// The viewer's state, written by the page into `<pre id="hh-status">`.
fn page_status(dom: &str) -> serde_json::Value {
    let start = dom.find("<pre id=\"hh-status\">").expect("status element") + 20;
    let end = start + dom[start..].find("</pre>").expect("end of status");
    serde_json::from_str(&dom[start..end].replace("&quot;", "\"")).expect("status is JSON")
}

/// templeSparseRing through the mesh, its report opened in Chromium: no JavaScript error, the
/// points, cameras and mesh drawn, a screenshot that is not one colour (kept as a test artefact),
/// and no request outside the workspace.
#[test]
fn the_report_opens_in_a_browser_and_draws_its_layers() {
    let Some(chrome) = chromium() else { return };
    let data = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/datasets/templeSparseRing/images");
    if !data.exists() {
        eprintln!("{} missing: skipping", data.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "--quiet",
        "reconstruct",
        data.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--until",
        "mesh",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = ws.join("report.html");
    assert!(html.exists(), "reconstruct writes the report");
    let size: u64 = std::fs::metadata(&html).unwrap().len()
        + std::fs::metadata(ws.join("report/scene.js")).unwrap().len();
    assert!(size < 15_000_000, "{size} bytes");
    let url = format!("file://{}", html.display());
    let profile = dir.path().join("profile");
    let netlog = dir.path().join("netlog.json");
    let o = browser(
        &chrome,
        &profile,
        &[
            "--dump-dom",
            "--window-size=1400,900",
            &format!("--log-net-log={}", netlog.display()),
        ],
        &url,
    );
    let dom = String::from_utf8_lossy(&o.stdout);
    let status = page_status(&dom);
    assert_eq!(status["errors"], serde_json::json!([]), "{status}");
    assert!(status["points"].as_u64().unwrap() > 1000, "{status}");
    assert!(status["triangles"].as_u64().unwrap() > 1000, "{status}");
    assert_eq!(status["cameras"].as_u64().unwrap(), 16, "{status}");
    // No request left the workspace. Local files never reach the network log; what does is
    // either the browser's own background traffic (priority IDLE) or a request of the page
    // (checked by hand: an <img> or <script> from the web logs priority LOW with Blink's
    // resource-loading annotation), which must not exist.
    let log = std::fs::read_to_string(&netlog).unwrap_or_default();
    for part in log.split("\"priority\":\"").skip(1) {
        let priority = &part[..part.find('"').unwrap_or(0)];
        let url = part
            .split("\"url\":\"")
            .nth(1)
            .and_then(|u| u.split('"').next())
            .unwrap_or("");
        assert!(
            priority == "IDLE" || !(url.starts_with("http:") || url.starts_with("https:")),
            "the page requested {url} ({priority})"
        );
    }
    for f in [html.clone(), ws.join("report/scene.js")] {
        let text = std::fs::read_to_string(&f).unwrap();
        for bad in [
            "src=\"http",
            "href=\"http",
            "url(http",
            "fetch(",
            "XMLHttpRequest",
        ] {
            assert!(!text.contains(bad), "{}: {bad}", f.display());
        }
    }
    // Clicking a camera (here the page's own entry point, #camera=N) looks through it.
    let o = browser(
        &chrome,
        &profile,
        &["--dump-dom", "--window-size=1400,900"],
        &format!("{url}#camera=3"),
    );
    let status = page_status(&String::from_utf8_lossy(&o.stdout));
    assert_eq!(status["through"], 3, "{status}");
    assert_eq!(status["errors"], serde_json::json!([]), "{status}");
    // The viewer alone at 1280×720: not blank.
    let shot = dir.path().join("viewer.png");
    let o = browser(
        &chrome,
        &profile,
        &[
            "--window-size=1280,720",
            "--virtual-time-budget=4000",
            &format!("--screenshot={}", shot.display()),
        ],
        &format!("{url}#viewer"),
    );
    assert!(shot.exists(), "no screenshot: {}", stderr(&o));
    let img = image::open(&shot).unwrap().to_rgb8();
    let mut colours = std::collections::HashSet::new();
    for p in img.pixels() {
        colours.insert(p.0);
    }
    assert!(
        colours.len() > 200,
        "{} colours: blank canvas",
        colours.len()
    );
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("report-templeSparseRing.png");
    std::fs::copy(&shot, &keep).unwrap();
    eprintln!("screenshot kept: {}", keep.display());
}

/// A workspace with only ingest and features gets a report of what exists, saying what is
/// missing; `handheld report` does not fail.
#[test]
fn a_partial_workspace_gets_a_report_of_what_exists() {
    let dir = tempfile::tempdir().unwrap();
    let photos = photo_folder(dir.path(), 4);
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "--quiet",
        "reconstruct",
        photos.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--until",
        "features",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_file(ws.join("report.html")).ok();
    let o = handheld(&["--json", "report", ws.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let missing: Vec<&str> = v["missing"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|m| m.as_str())
        .collect();
    assert!(
        missing.contains(&"sparse") && missing.contains(&"mesh"),
        "{v}"
    );
    let html = std::fs::read_to_string(ws.join("report.html")).unwrap();
    assert!(html.contains("Not run yet: sparse"));
    assert_eq!(v["images"], 4);
}
