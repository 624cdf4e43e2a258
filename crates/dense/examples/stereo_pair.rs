//! Matches a rectified pair and writes the left disparity as PFM (for
//! `../shared/tools/eval_stereo.py`).
//!
//! ```text
//! cargo run --release -p handheld-dense --example stereo_pair -- \
//!     LEFT.png RIGHT.png OUT.pfm [--method sgm|dp] [--max-disparity 63] [--runs 5] \
//!     [--set KEY=VALUE]... [--valid-only]
//! ```
//!
//! `--set` overrides an option: `p1`, `p2`, `adaptive_p2_scale` (0 = off), `paths` (4|8),
//! `census` (e.g. `9x7`), `cost` (`census`|`zncc`), `window`, `occlusion_cost`, `lr_tolerance`
//! (negative = off), `subpixel`, `median` (0|1), `hole_fill` (none|scanline|directional),
//! `speckle_size`, `speckle_range`.
//! Prints one JSON line: method, width, height, seconds (median of the runs, one reused
//! [`StereoMatcher`] as OpenCV reuses its `StereoSGBM` object), the first run's seconds (which also
//! allocates the volumes), density and the fraction of measured (not filled) pixels.
//! `--valid-only` writes only the measured pixels.

use std::error::Error;
use std::io::Write;
use std::time::Instant;

use handheld_core::FloatMap;
use handheld_dense::{
    HoleFill, MatchingCost, SgmPaths, StereoMatcher, StereoMethod, StereoOptions,
};

type Res<T> = Result<T, Box<dyn Error>>;

fn load(path: &str) -> Res<FloatMap> {
    let img = image::open(path)
        .map_err(|e| format!("cannot read {path}: {e}"))?
        .to_rgb8();
    Ok(FloatMap {
        width: img.width() as usize,
        height: img.height() as usize,
        channels: 3,
        data: img.as_raw().iter().map(|v| f32::from(*v)).collect(),
    })
}

fn write_pfm(path: &str, m: &FloatMap) -> Res<()> {
    let mut buf = format!("Pf\n{} {}\n-1\n", m.width, m.height).into_bytes();
    for y in (0..m.height).rev() {
        for v in &m.data[y * m.width..(y + 1) * m.width] {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(&buf))
        .map_err(|e| format!("cannot write {path}: {e}"))?;
    Ok(())
}

fn set(o: &mut StereoOptions, kv: &str) -> Res<()> {
    let (k, v) = kv
        .split_once('=')
        .ok_or_else(|| format!("--set expects KEY=VALUE, got {kv}"))?;
    let flag = |v: &str| v == "1" || v == "true";
    match k {
        "p1" => o.p1 = v.parse()?,
        "p2" => o.p2 = v.parse()?,
        "adaptive_p2_scale" => {
            let s: f32 = v.parse()?;
            o.adaptive_p2_scale = (s > 0.0).then_some(s);
        }
        "paths" => {
            o.sgm_paths = if v == "4" {
                SgmPaths::Four
            } else {
                SgmPaths::Eight
            }
        }
        "census" => {
            let (w, h) = v.split_once('x').ok_or("census expects WxH")?;
            o.cost = MatchingCost::Census {
                width: w.parse()?,
                height: h.parse()?,
            };
        }
        "cost" => {
            o.cost = match v {
                "zncc" => MatchingCost::Zncc,
                "census" => MatchingCost::Census {
                    width: 9,
                    height: 7,
                },
                _ => return Err(format!("unknown cost {v}").into()),
            }
        }
        "window" => o.window = v.parse()?,
        "occlusion_cost" => o.occlusion_cost = v.parse()?,
        "lr_tolerance" => {
            let t: f32 = v.parse()?;
            o.lr_tolerance = (t >= 0.0).then_some(t);
        }
        "subpixel" => o.subpixel = flag(v),
        "median" => o.median = flag(v),
        "hole_fill" => {
            o.hole_fill = match v {
                "none" => HoleFill::None,
                "scanline" => HoleFill::Scanline,
                "directional" => HoleFill::Directional,
                _ => return Err(format!("unknown hole_fill {v}").into()),
            }
        }
        "speckle_size" => o.speckle_size = v.parse()?,
        "speckle_range" => o.speckle_range = v.parse()?,
        _ => return Err(format!("unknown option {k}").into()),
    }
    Ok(())
}

fn main() -> Res<()> {
    // Stage timings: RUST_LOG=handheld_dense=debug.
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut pos = Vec::new();
    let (mut method, mut max_d, mut runs, mut sets, mut valid_only) =
        ("sgm".to_string(), 63, 5, Vec::new(), false);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--method" => method = val()?.clone(),
            "--max-disparity" => max_d = val()?.parse()?,
            "--runs" => runs = val()?.parse()?,
            "--set" => sets.push(val()?.clone()),
            "--valid-only" => valid_only = true,
            _ => pos.push(a.clone()),
        }
    }
    let [left, right, out] = pos.as_slice() else {
        return Err("usage: stereo_pair LEFT RIGHT OUT.pfm [--method sgm|dp] \
                    [--max-disparity N] [--runs N] [--set K=V]... [--valid-only]"
            .into());
    };
    let m = match method.as_str() {
        "sgm" => StereoMethod::Sgm,
        "dp" => StereoMethod::Dp,
        _ => return Err(format!("unknown method {method}").into()),
    };
    let mut opts = StereoOptions {
        max_disparity: max_d,
        ..StereoOptions::for_method(m)
    };
    for kv in &sets {
        set(&mut opts, kv)?;
    }
    let (l, r) = (load(left)?, load(right)?);
    // Like OpenCV's StereoSGBM object, one matcher is reused over the runs; the first run also
    // allocates its volumes and is reported separately.
    let mut matcher = StereoMatcher::new(opts)?;
    let mut times = Vec::new();
    let mut disp = None;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        disp = Some(matcher.match_pair(&l, &r)?);
        times.push(t.elapsed().as_secs_f64());
    }
    let first = times[0];
    let disp = disp.ok_or("no run")?;
    times.sort_by(f64::total_cmp);
    let map = if valid_only {
        disp.valid_float_map()
    } else {
        disp.to_float_map()
    };
    write_pfm(out, &map)?;
    println!(
        "{}",
        serde_json::json!({
            "method": method,
            "width": disp.width,
            "height": disp.height,
            "seconds": (times[times.len() / 2] * 1e4).round() / 1e4,
            "first_run_seconds": (first * 1e4).round() / 1e4,
            "density": (disp.density() * 1e4).round() / 100.0,
            "measured": (disp.valid_fraction() * 1e4).round() / 100.0,
        })
    );
    Ok(())
}
