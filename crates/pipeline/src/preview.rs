//! False-colour previews of depth and visibility maps, for a person to look at.

use std::path::Path;

use handheld_core::FloatMap;

use crate::error::{PipelineError, Result};

/// Writes a false-colour PNG of a one-channel map: a blue → cyan → yellow → red ramp between the
/// 2nd and 98th percentiles of its positive finite values; black where a value is missing.
pub fn write_preview(map: &FloatMap, path: &Path) -> Result<()> {
    let mut vals: Vec<f32> = map
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    vals.sort_by(f32::total_cmp);
    let (lo, hi) = match vals.len() {
        0 => (0.0, 1.0),
        n => (vals[n / 50], vals[n - 1 - n / 50].max(vals[n / 50] + 1e-6)),
    };
    let mut img = image::RgbImage::new(map.width as u32, map.height as u32);
    for (i, p) in img.pixels_mut().enumerate() {
        let v = map.data[i];
        if v.is_finite() && v > 0.0 {
            let t = ((v - lo) / (hi - lo)).clamp(0.0, 1.0);
            p.0 = ramp(t);
        }
    }
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| PipelineError::workspace(path, format!("cannot encode the preview: {e}")))?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Blue → cyan → yellow → red.
pub fn ramp(t: f32) -> [u8; 3] {
    let c = |a: f32, b: f32, s: f32| (a + (b - a) * s).round().clamp(0.0, 255.0) as u8;
    if t < 0.33 {
        let s = t / 0.33;
        [c(40.0, 30.0, s), c(30.0, 200.0, s), c(160.0, 230.0, s)]
    } else if t < 0.66 {
        let s = (t - 0.33) / 0.33;
        [c(30.0, 250.0, s), c(200.0, 220.0, s), c(230.0, 40.0, s)]
    } else {
        let s = (t - 0.66) / 0.34;
        [c(250.0, 200.0, s), c(220.0, 30.0, s), c(40.0, 20.0, s)]
    }
}
