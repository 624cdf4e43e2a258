//! Inline SVG plots, drawn by hand (no plotting service): histograms, a bar chart, a matrix and
//! a 2D scatter of the camera path.

use std::fmt::Write;

use crate::html::esc;

const W: f64 = 420.0;
const H: f64 = 240.0;
const ML: f64 = 48.0;
const MR: f64 = 12.0;
const MT: f64 = 26.0;
const MB: f64 = 40.0;

fn frame(title: &str, xlabel: &str, body: &str) -> String {
    format!(
        r##"<svg class="plot" viewBox="0 0 {W} {H}" width="{W}" height="{H}" xmlns="http://www.w3.org/2000/svg"><text x="{tx}" y="16" text-anchor="middle" class="t">{t}</text>{body}<text x="{tx}" y="{ly}" text-anchor="middle" class="l">{x}</text></svg>"##,
        tx = W / 2.0,
        ly = H - 6.0,
        t = esc(title),
        x = esc(xlabel),
    )
}

/// A compact number for axis labels.
fn num(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 10.0 {
        format!("{:.0}", v)
    } else if v.abs() >= 1.0 {
        format!("{:.1}", v)
    } else {
        format!("{:.2}", v)
    }
}

/// Bars with labels under them (counts or seconds).
fn bars(values: &[f64], labels: &[String], ymax: f64) -> String {
    let mut s = String::new();
    let n = values.len().max(1) as f64;
    let pw = W - ML - MR;
    let ph = H - MT - MB;
    let bw = pw / n;
    let _ = write!(
        s,
        r#"<line x1="{ML}" y1="{y0}" x2="{x1}" y2="{y0}" class="a"/><line x1="{ML}" y1="{MT}" x2="{ML}" y2="{y0}" class="a"/>"#,
        y0 = MT + ph,
        x1 = ML + pw
    );
    for k in 0..=4 {
        let v = ymax * k as f64 / 4.0;
        let y = MT + ph - ph * k as f64 / 4.0;
        let _ = write!(
            s,
            r#"<text x="{x}" y="{y}" text-anchor="end" class="k">{v}</text>"#,
            x = ML - 4.0,
            y = y + 3.0,
            v = num(v)
        );
    }
    let every = (values.len() / 8).max(1);
    for (i, v) in values.iter().enumerate() {
        let h = if ymax > 0.0 { ph * v / ymax } else { 0.0 };
        let x = ML + bw * i as f64;
        let _ = write!(
            s,
            r#"<rect x="{x:.1}" y="{y:.1}" width="{w:.1}" height="{h:.1}" class="b"><title>{lab}: {v}</title></rect>"#,
            y = MT + ph - h,
            w = (bw - 1.0).max(0.5),
            lab = esc(labels.get(i).map_or("", |l| l.as_str())),
            v = num(*v)
        );
        if i % every == 0 {
            if let Some(l) = labels.get(i) {
                let _ = write!(
                    s,
                    r#"<text x="{x:.1}" y="{y}" text-anchor="middle" class="k">{l}</text>"#,
                    x = x + bw / 2.0,
                    y = MT + ph + 12.0,
                    l = esc(l)
                );
            }
        }
    }
    s
}

/// A histogram of `values` over `[lo, hi]` in `bins` bins (values above go in the last bin).
pub fn histogram(
    title: &str,
    xlabel: &str,
    values: &[f64],
    lo: f64,
    hi: f64,
    bins: usize,
) -> String {
    let mut counts = vec![0.0f64; bins.max(1)];
    for v in values {
        if !v.is_finite() {
            continue;
        }
        let t = ((v - lo) / (hi - lo) * bins as f64).floor();
        let k = (t.max(0.0) as usize).min(bins - 1);
        counts[k] += 1.0;
    }
    let ymax = counts.iter().fold(1.0f64, |a, b| a.max(*b));
    let labels: Vec<String> = (0..bins)
        .map(|k| num(lo + (hi - lo) * k as f64 / bins as f64))
        .collect();
    frame(title, xlabel, &bars(&counts, &labels, ymax))
}

/// A bar chart of named values.
pub fn bar_chart(title: &str, xlabel: &str, items: &[(String, f64)]) -> String {
    let values: Vec<f64> = items.iter().map(|i| i.1).collect();
    let labels: Vec<String> = items.iter().map(|i| i.0.clone()).collect();
    let ymax = values.iter().fold(1e-9f64, |a, b| a.max(*b)) * 1.1;
    frame(title, xlabel, &bars(&values, &labels, ymax))
}

/// A square matrix of values (0 = empty), darker for larger, as COLMAP's match matrix.
pub fn matrix(title: &str, n: usize, cells: &[(usize, usize, f64)]) -> String {
    let size = (H - MT - MB).min(W - ML - MR);
    let c = size / n.max(1) as f64;
    let vmax = cells.iter().fold(1e-9f64, |a, b| a.max(b.2));
    let x0 = (W - size) / 2.0;
    let mut s = format!(r#"<rect x="{x0}" y="{MT}" width="{size}" height="{size}" class="bg"/>"#);
    for &(i, j, v) in cells {
        for (a, b) in [(i, j), (j, i)] {
            let shade = (v / vmax).sqrt();
            let _ = write!(
                s,
                r#"<rect x="{x:.2}" y="{y:.2}" width="{c:.2}" height="{c:.2}" fill="rgb({r},{g},{bl})"><title>{i} – {j}: {v:.0}</title></rect>"#,
                x = x0 + c * b as f64,
                y = MT + c * a as f64,
                r = (235.0 - 200.0 * shade) as u8,
                g = (240.0 - 170.0 * shade) as u8,
                bl = (250.0 - 90.0 * shade) as u8,
            );
        }
    }
    frame(
        title,
        &format!("image index (0 … {})", n.saturating_sub(1)),
        &s,
    )
}

/// Points in 2D (the camera path seen from one side), joined in order, the first one marked.
pub fn path(title: &str, xlabel: &str, pts: &[[f64; 2]], extra: &[[f64; 2]]) -> String {
    let all: Vec<&[f64; 2]> = pts.iter().chain(extra).collect();
    if all.is_empty() {
        return frame(title, xlabel, "");
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &all {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-12) * 1.1;
    let (cx, cy) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
    let pw = W - ML - MR;
    let ph = H - MT - MB;
    let scale = pw.min(ph) / span;
    let map = |p: &[f64; 2]| {
        (
            ML + pw / 2.0 + (p[0] - cx) * scale,
            MT + ph / 2.0 - (p[1] - cy) * scale,
        )
    };
    let mut s = String::new();
    for p in extra {
        let (x, y) = map(p);
        let _ = write!(s, r#"<circle cx="{x:.1}" cy="{y:.1}" r="0.8" class="pt"/>"#);
    }
    let line: Vec<String> = pts
        .iter()
        .map(|p| {
            let (x, y) = map(p);
            format!("{x:.1},{y:.1}")
        })
        .collect();
    let _ = write!(s, r#"<polyline points="{}" class="p"/>"#, line.join(" "));
    for (k, p) in pts.iter().enumerate() {
        let (x, y) = map(p);
        let _ = write!(
            s,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="{r}" class="{c}"><title>camera {k}</title></circle>"#,
            r = if k == 0 { 4 } else { 2 },
            c = if k == 0 { "c0" } else { "c" }
        );
    }
    frame(title, xlabel, &s)
}
