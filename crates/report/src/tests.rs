//! The report's own tests: what it shows, and that no data can become markup or script.
use super::*;
use image::RgbImage;

/// A failed image shows with its reason, an image's note under it, a warning, the metric frame's
/// source and a missing stage in the verdict,
/// and every file is inside `report/` or the page itself.
#[test]
fn failed_images_warnings_and_missing_stages_are_shown() {
    let input = ReportInput {
        title: "t".into(),
        verdict: Verdict {
            images_in: 2,
            registered: Some(1),
            metric_frame: Some("calibrated incremental (two-view focal length)".into()),
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
                note: Some("a copy of b.jpg".into()),
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
    assert!(html.contains("a copy of b.jpg"));
    assert!(html.contains("calibrated incremental (two-view focal length)"));
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

/// Names that are markup, quotes, ampersands, non-ASCII, line separators and URL syntax.
const HOSTILE: [&str; 7] = [
    "<img src=x onerror=alert(1)>.jpg",
    "\"quote'.jpg",
    "a&b.jpg",
    "été_日本.jpg",
    "</script><script>alert(2)</script>.jpg",
    "line\u{2028}sep\u{2029}.jpg",
    "javascript:alert(3)#?%41.jpg",
];

fn hostile_input() -> ReportInput {
    let cam = |k: usize, name: &str| {
        (
            k,
            ViewerCamera {
                name: name.into(),
                c: [k as f64, 0.0, 0.0],
                r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                f: 100.0,
                aspect: 1.0,
                cx: 4.0,
                cy: 3.0,
                w: 8,
                h: 6,
                registered: true,
                thumb: String::new(),
            },
        )
    };
    ReportInput {
        title: format!("Handheld report: /tmp/{}", HOSTILE[0]),
        warnings: HOSTILE
            .iter()
            .map(|h| ReportWarning {
                code: h.to_string(),
                text: format!("sparse: {h}"),
                advice: Some(h.to_string()),
                details: Some(h.to_string()),
            })
            .collect(),
        missing: vec![HOSTILE[4].into()],
        images: HOSTILE
            .iter()
            .map(|h| ImageEntry {
                name: h.to_string(),
                thumb: Some(RgbImage::new(8, 6)),
                registered: Some(false),
                reason: Some(h.to_string()),
                depth_preview: Some(format!("dense/preview/{h}.depth.png")),
                fill: Some(0.5),
                ..Default::default()
            })
            .collect(),
        cameras: HOSTILE.iter().enumerate().map(|(k, h)| cam(k, h)).collect(),
        stage_times: vec![(HOSTILE[0].into(), 1.0)],
        renders: vec![
            (HOSTILE[1].into(), format!("render/{}.mp4", HOSTILE[0])),
            (HOSTILE[4].into(), format!("mesh/{}.png", HOSTILE[6])),
        ],
        ..Default::default()
    }
}

fn file(out: &ReportFiles, rel: &str) -> String {
    let f = out.files.iter().find(|f| f.0 == Path::new(rel)).unwrap();
    String::from_utf8(f.1.clone()).unwrap()
}

/// Every string from data reaches the page as text: no element, attribute, handler or script
/// comes from a name, a warning, a reason, a path, a label or the title.
#[test]
fn hostile_names_are_text_in_the_page() {
    let out = render_report(&hostile_input()).unwrap();
    let html = file(&out, REPORT_HTML);
    for bad in [
        "<img src=x",
        "<script>alert",
        "onerror=\"",
        "=\"javascript:",
    ] {
        assert!(!html.contains(bad), "{bad} in the page");
    }
    // Two scripts: scene.js by its path, the viewer inline.
    assert_eq!(html.matches("<script").count(), 2);
    assert_eq!(html.matches("</script>").count(), 2);
    assert!(html.contains("&lt;img src=x onerror=alert(1)&gt;.jpg"));
    assert!(html.contains("&quot;quote&#39;.jpg") && html.contains("a&amp;b.jpg"));
    assert!(html.contains("été_日本.jpg"));
    assert!(html.contains(
        "src=\"dense/preview/%3Cimg%20src%3Dx%20onerror%3Dalert%281%29%3E.jpg.depth.png\""
    ));
    assert!(html.contains("src=\"mesh/javascript%3Aalert%283%29%23%3F%2541.jpg.png\""));
    // Every tag's attributes: none is an event handler.
    for tag in html.split('<').skip(1) {
        let tag = &tag[..tag.find('>').unwrap_or(tag.len())];
        for attr in tag.split_whitespace().skip(1) {
            assert!(!attr.starts_with("on"), "<{tag}>");
        }
    }
}

/// The scene's names are JSON escaped for JavaScript: no `<`, no line separator, and the same
/// strings when parsed.
#[test]
fn hostile_names_are_json_strings_in_the_scene() {
    let out = render_report(&hostile_input()).unwrap();
    let js = file(&out, "report/scene.js");
    assert!(!js.contains('<') && !js.contains('>') && !js.contains('&'));
    assert!(!js.contains('\u{2028}') && !js.contains('\u{2029}'));
    let json = js
        .strip_prefix("window.HANDHELD = ")
        .and_then(|s| s.strip_suffix(";\n"))
        .unwrap();
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    for (k, h) in HOSTILE.iter().enumerate() {
        assert_eq!(v["cameras"][k]["name"], *h);
    }
}

/// The page's policy comes first in its head, allows no network, and allows exactly its own
/// inline stylesheet and viewer by their hashes.
#[test]
fn the_page_carries_a_content_security_policy_with_its_inline_hashes() {
    let out = render_report(&hostile_input()).unwrap();
    let html = file(&out, REPORT_HTML);
    let head = &html[..html.find("<title>").unwrap()];
    let meta = "<meta http-equiv=\"Content-Security-Policy\" content=\"";
    let start = head
        .find(meta)
        .expect("CSP meta in the head, before the title")
        + meta.len();
    let csp = &head[start..start + head[start..].find('"').unwrap()];
    for part in [
        "default-src 'none'",
        "connect-src 'none'",
        "object-src 'none'",
        "base-uri 'none'",
        "script-src 'self' 'sha256-",
    ] {
        assert!(csp.contains(part), "{part} missing: {csp}");
    }
    assert!(!csp.contains("unsafe") && !csp.contains("http"), "{csp}");
    let inner = |open: &str, close: &str| {
        let a = html.find(open).unwrap() + open.len();
        html[a..a + html[a..].find(close).unwrap()].to_string()
    };
    let style = inner("<style>", "</style>");
    let script = inner("<script>", "</script>");
    assert!(csp.contains(&html::sha256_source(&style)));
    assert!(csp.contains(&html::sha256_source(&script)));
}
