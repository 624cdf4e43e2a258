//! The report in a real browser: Debian's Chromium, headless, software WebGL (SwiftShader), the
//! network blocked. The page reports its own state into `<pre id="hh-status">` (errors, what
//! each layer drew, WebGL errors, a lost context) and `--dump-dom` reads it back; the hash of the
//! URL drives the viewer as a person does (`#camera=N` selects a camera as a click on it does,
//! `#layers=mesh` sets the layer toggles). Without Chromium (or the temple data set) these tests
//! show as ignored with the reason, and fail under `CI` (which installs Chromium).

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Chromium (the program `$HANDHELD_CHROMIUM` names, or `chromium`), or a panic naming it; the
/// tests that call this are marked `cfg_attr(not(has_chromium), ignore)`, so a machine without it
/// shows them as ignored, and CI (which installs it) fails.
#[track_caller]
fn chromium() -> PathBuf {
    handheld_testkit::needs::chromium();
    PathBuf::from(handheld_testkit::needs::chromium_program())
}

/// One headless run of `url`; the page's console goes to stderr (`--enable-logging=stderr`).
fn browser(chrome: &Path, profile: &Path, extra: &[&str], url: &str) -> Output {
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
            "--enable-logging=stderr",
            "--v=0",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(url)
        .output()
        .expect("chromium runs")
}

/// The page's DOM after it ran (`--dump-dom`), failing on any Content-Security-Policy message
/// in the console: the policy must not block anything the page itself needs.
fn dump_dom(chrome: &Path, profile: &Path, extra: &[&str], url: &str) -> String {
    // Virtual time lets what the page does later (the atlas's load, an image's onerror) happen.
    let mut args = vec![
        "--dump-dom",
        "--window-size=1400,900",
        "--virtual-time-budget=2000",
    ];
    args.extend_from_slice(extra);
    let o = browser(chrome, profile, &args, url);
    let console = stderr(&o);
    for line in console.lines() {
        assert!(
            !line.contains("Content Security Policy"),
            "{url}: the policy blocked something: {line}"
        );
    }
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Text as `--dump-dom` serialises it back to the characters.
fn unescape_text(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&nbsp;", "\u{a0}")
        .replace("&amp;", "&")
}

/// Text as `--dump-dom` serialises it (a text node: `&`, `<`, `>` and no-break space escaped).
fn escape_text(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('\u{a0}', "&nbsp;")
}

/// The inside of the element that starts with `open` (no nested element of the same kind).
fn element<'a>(dom: &'a str, open: &str, close: &str) -> &'a str {
    let start = dom
        .find(open)
        .unwrap_or_else(|| panic!("no {open} in the page:\n{dom}"))
        + open.len();
    let end = start + dom[start..].find(close).expect("end of element");
    &dom[start..end]
}

/// The viewer's state, written by the page into `<pre id="hh-status">`.
fn page_status(dom: &str) -> serde_json::Value {
    let text = unescape_text(element(dom, "<pre id=\"hh-status\">", "</pre>"));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("status is not JSON ({e}): {text}"))
}

/// A drawn frame without error: no script or policy error, no GL error, the context alive.
fn assert_clean(status: &serde_json::Value) {
    assert_eq!(status["errors"], serde_json::json!([]), "{status}");
    assert_eq!(status["context_lost"], false, "{status}");
    assert!(status["frames"].as_u64().unwrap_or(0) > 0, "{status}");
}

/// A screenshot of `url` at 1280×720.
fn screenshot(chrome: &Path, profile: &Path, url: &str, png: &Path) -> image::RgbImage {
    let o = browser(
        chrome,
        profile,
        &[
            "--window-size=1280,720",
            "--virtual-time-budget=4000",
            &format!("--screenshot={}", png.display()),
        ],
        url,
    );
    assert!(png.exists(), "no screenshot of {url}: {}", stderr(&o));
    image::open(png).unwrap().to_rgb8()
}

/// Distinct colours, and the share of pixels away from the most common one (the background).
fn colours_and_coverage(img: &image::RgbImage) -> (usize, f64) {
    let mut count = std::collections::HashMap::new();
    for p in img.pixels() {
        *count.entry(p.0).or_insert(0usize) += 1;
    }
    let bg = count.iter().max_by_key(|c| *c.1).map(|c| *c.0).unwrap();
    let away = img
        .pixels()
        .filter(|p| (0..3).any(|k| (p.0[k] as i32 - bg[k] as i32).abs() > 12))
        .count();
    (
        count.len(),
        away as f64 / (img.width() * img.height()) as f64,
    )
}

/// Keeps a screenshot as a test artefact.
fn keep(png: &Path, name: &str) {
    let kept = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::copy(png, &kept).unwrap();
    eprintln!("screenshot kept: {}", kept.display());
}

/// The temple's photos, or a panic naming the missing data set (tests marked
/// `cfg_attr(not(has_temple), ignore)`).
#[track_caller]
fn temple() -> PathBuf {
    dataset("templeSparseRing").join("images")
}

/// No request of the page left the workspace. Local files never reach the network log; what
/// does is either the browser's own background traffic (priority IDLE) or a request of the page
/// (an <img> or <script> from the web logs priority LOW with Blink's resource-loading
/// annotation), which must not exist.
fn assert_no_network(netlog: &Path, ws: &Path) {
    let log = std::fs::read_to_string(netlog).unwrap_or_default();
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
    for f in [ws.join("report.html"), ws.join("report/scene.js")] {
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
}

/// templeSparseRing through the mesh, its report opened in Chromium: no JavaScript error, no
/// WebGL error, no lost context, nothing the policy blocks; the points, cameras and mesh drawn;
/// a camera looked through; the mesh layer alone (points and cameras off through their toggles)
/// covers the canvas with the atlas's colours, while no layer at all leaves it one colour; and
/// no request outside the workspace.
#[test]
#[cfg_attr(
    not(all(has_chromium, has_temple)),
    ignore = "needs chromium and ../shared/datasets/templeSparseRing (missing)"
)]
fn the_report_opens_in_a_browser_and_draws_its_layers() {
    let chrome = chromium();
    let data = temple();
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
    assert!(std::fs::read_to_string(&html)
        .unwrap()
        .contains("<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none';"));
    let url = format!("file://{}", html.display());
    let profile = dir.path().join("profile");
    let netlog = dir.path().join("netlog.json");
    let log_arg = format!("--log-net-log={}", netlog.display());
    let status = page_status(&dump_dom(&chrome, &profile, &[&log_arg], &url));
    assert_clean(&status);
    // The frame time of a turning view, at the resolution scale the viewer chose for it, and of
    // the still frame at full resolution (printed, not judged: a test is no benchmark).
    let ms = status["ms_per_frame"]
        .as_f64()
        .expect("the viewer timed its frames");
    let full = status["full_ms_per_frame"]
        .as_f64()
        .expect("and its still frame");
    let scale = status["scale"].as_f64().expect("and says at which scale");
    println!(
        "viewer, templeSparseRing at 1280×720: {ms:.1} ms per frame of a turning view ({:.0} fps) at resolution scale {scale:.2}; still frame {full:.1} ms",
        1000.0 / ms
    );
    assert!(
        ms > 0.0 && full > 0.0 && (0.0..=1.0).contains(&scale),
        "{status}"
    );
    assert!(status["points"].as_u64().unwrap() > 1000, "{status}");
    assert!(status["triangles"].as_u64().unwrap() > 1000, "{status}");
    assert_eq!(status["cameras"].as_u64().unwrap(), 16, "{status}");
    assert_no_network(&netlog, &ws);
    // Clicking a camera (here the page's own entry point, #camera=N) looks through it.
    let status = page_status(&dump_dom(
        &chrome,
        &profile,
        &[],
        &format!("{url}#camera=3"),
    ));
    assert_eq!(status["through"], 3, "{status}");
    assert_clean(&status);
    // The mesh alone: the points and cameras toggled off.
    let mesh_only = format!("{url}#viewer&layers=mesh");
    let status = page_status(&dump_dom(&chrome, &profile, &[], &mesh_only));
    assert_clean(&status);
    assert_eq!(status["points"], 0, "{status}");
    assert_eq!(status["cameras"], 0, "{status}");
    assert!(status["triangles"].as_u64().unwrap() > 1000, "{status}");
    let shot = dir.path().join("mesh.png");
    let (colours, coverage) =
        colours_and_coverage(&screenshot(&chrome, &profile, &mesh_only, &shot));
    keep(&shot, "report-templeSparseRing-mesh.png");
    // Textured (an untextured mesh is one flat grey) and covering a good part of the view.
    assert!(colours > 200, "{colours} colours: the mesh is not textured");
    assert!(
        coverage > 0.005,
        "the mesh covers {:.1} %",
        coverage * 100.0
    );
    // No layer: the check above would fail on an empty canvas.
    let none = dir.path().join("none.png");
    let url_none = format!("{url}#viewer&layers=");
    let (colours, coverage) =
        colours_and_coverage(&screenshot(&chrome, &profile, &url_none, &none));
    assert!(
        colours < 50 && coverage < 0.01,
        "{colours} colours, {coverage}"
    );
    // Everything at 1280×720.
    let shot = dir.path().join("viewer.png");
    let (colours, _) = colours_and_coverage(&screenshot(
        &chrome,
        &profile,
        &format!("{url}#viewer"),
        &shot,
    ));
    assert!(colours > 200, "{colours} colours: blank canvas");
    keep(&shot, "report-templeSparseRing.png");
}

/// Names of photos that are markup, quotes, an ampersand, non-ASCII, a line separator, URL
/// syntax and a long name; each would set `data-pwned` on the body if it ran as script.
fn hostile_names() -> Vec<String> {
    let long = format!("05{}.jpg", &"long_name_".repeat(20)[..194]);
    let mut v: Vec<String> = [
        "00<img src=x onerror=document.body.dataset.pwned=1>.jpg",
        "01<svg onload=document.body.dataset.pwned=2>.jpg",
        "02\"quote'.jpg",
        "03a&b.jpg",
        "04été_日本.jpg",
    ]
    .map(String::from)
    .to_vec();
    assert_eq!(long.len(), 200);
    v.push(long);
    v.push("06line\u{2028}sep.jpg".into());
    v.push("07#x?y=%41.jpg".into());
    v
}

/// Photos with hostile names, reconstructed to a sparse model: the page shows each name as text
/// in its grid and, when its camera is selected (as a click does), in the camera panel; no
/// injected script runs; the page carries its Content-Security-Policy and nothing is blocked.
#[test]
#[cfg_attr(
    not(all(has_chromium, has_temple)),
    ignore = "needs chromium and ../shared/datasets/templeSparseRing (missing)"
)]
fn hostile_file_names_are_shown_as_text_and_never_run() {
    let chrome = chromium();
    let data = temple();
    let dir = tempfile::tempdir().unwrap();
    let photos = dir.path().join("photos");
    std::fs::create_dir_all(&photos).unwrap();
    let mut sources: Vec<PathBuf> = std::fs::read_dir(&data)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    sources.sort();
    let names = hostile_names();
    for (k, src) in sources.iter().enumerate() {
        // The first photos take the hostile names (the content is PNG; ingest reads the format
        // from the bytes), in the same order; the rest keep theirs.
        let name = names
            .get(k)
            .cloned()
            .unwrap_or_else(|| format!("{k:02}{}", src.file_name().unwrap().to_string_lossy()));
        std::fs::copy(src, photos.join(&name)).unwrap();
    }
    let ws = dir.path().join("ws");
    let o = handheld(&[
        "--quiet",
        "reconstruct",
        photos.to_str().unwrap(),
        "-o",
        ws.to_str().unwrap(),
        "--until",
        "sparse",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(ws.join("report.html")).unwrap();
    assert!(
        html.contains("<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none';")
    );
    assert!(!html.contains("<img src=x") && !html.contains("<svg onload"));
    // The cameras' order in the scene.
    let scene = std::fs::read_to_string(ws.join("report/scene.js")).unwrap();
    let json = scene
        .strip_prefix("window.HANDHELD = ")
        .and_then(|s| s.strip_suffix(";\n"))
        .expect("scene.js is one assignment");
    let scene: serde_json::Value = serde_json::from_str(json).unwrap();
    let cameras: Vec<String> = scene["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["name"].as_str().unwrap().to_string())
        .collect();
    let url = format!("file://{}", ws.join("report.html").display());
    let profile = dir.path().join("profile");
    let dom = dump_dom(&chrome, &profile, &[], &url);
    assert_clean(&page_status(&dom));
    assert!(!dom.contains("data-pwned"), "a name ran as script");
    for name in &names {
        assert!(
            dom.contains(&escape_text(name)),
            "{name} is not shown as text"
        );
    }
    let mut selected = 0;
    for name in &names {
        let Some(n) = cameras.iter().position(|c| c == name) else {
            eprintln!("{name}: not registered, not a camera");
            continue;
        };
        let dom = dump_dom(&chrome, &profile, &[], &format!("{url}#camera={n}"));
        let status = page_status(&dom);
        assert_clean(&status);
        assert_eq!(status["through"], n, "{status}");
        assert!(!dom.contains("data-pwned"), "{name} ran as script");
        let panel = element(
            &dom,
            "<div id=\"hh-photo\">",
            "</div><pre id=\"hh-status\">",
        );
        assert_eq!(
            panel.matches('<').count(),
            3,
            "the photo and the name: {panel}"
        );
        assert!(panel.starts_with("<img src=\"report/thumbs/"), "{panel}");
        let shown = element(panel, "<div class=\"hh-name\">", "</div>");
        assert_eq!(unescape_text(shown), *name);
        selected += 1;
    }
    // The injection attempts themselves must have been selected.
    assert!(
        cameras.iter().any(|c| c.starts_with("00<img")) && selected >= 4,
        "{selected} hostile cameras of {cameras:?}"
    );
    let shot = dir.path().join("hostile.png");
    let n = cameras.iter().position(|c| c == &names[0]).unwrap();
    screenshot(&chrome, &profile, &format!("{url}#camera={n}"), &shot);
    keep(&shot, "report-hostile-names.png");
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
