//! Portable Float Map (PFM) files for [`FloatMap`]s such as depth maps.
//!
//! Header: `Pf` (one channel) or `PF` (three channels), then `width height`, then a scale whose sign
//! gives the byte order (negative: little-endian, positive: big-endian). The `f32` samples follow with
//! rows stored bottom to top; [`FloatMap`] is top row first, so rows are flipped both ways. Files are
//! written little-endian and atomically.

use std::fs;
use std::path::Path;

use handheld_core::FloatMap;

use crate::atomic::write_atomic;
use crate::error::{IoError, Result};

/// Writes a 1- or 3-channel map as a little-endian PFM.
pub fn write_pfm(path: &Path, map: &FloatMap) -> Result<()> {
    let tag = match map.channels {
        1 => "Pf",
        3 => "PF",
        c => {
            return Err(IoError::Input {
                path: path.to_path_buf(),
                reason: format!("PFM holds 1 or 3 channels, not {c}"),
            })
        }
    };
    let row_len = map.width * map.channels;
    if map
        .width
        .checked_mul(map.height)
        .and_then(|n| n.checked_mul(map.channels))
        != Some(map.data.len())
    {
        return Err(IoError::Input {
            path: path.to_path_buf(),
            reason: format!(
                "{} values for a {}x{}x{} map",
                map.data.len(),
                map.width,
                map.height,
                map.channels
            ),
        });
    }
    write_atomic(path, |w| {
        write!(w, "{tag}\n{} {}\n-1\n", map.width, map.height)?;
        let mut buf = Vec::with_capacity(row_len * 4);
        for y in (0..map.height).rev() {
            buf.clear();
            for v in &map.data[y * row_len..(y + 1) * row_len] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            w.write_all(&buf)?;
        }
        Ok(())
    })
}

/// Reads a PFM of either byte order into a top-row-first [`FloatMap`].
pub fn read_pfm(path: &Path) -> Result<FloatMap> {
    let bytes = fs::read(path).map_err(|e| IoError::io(path, e))?;
    let bad = |reason: String| IoError::format(path, reason);

    // Four whitespace-separated header tokens, then exactly one whitespace byte before the data.
    let mut pos = 0;
    let mut tokens = Vec::with_capacity(4);
    for _ in 0..4 {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 64 {
            pos += 1;
        }
        if start == pos {
            return Err(bad(
                "truncated PFM header (expected `PF`/`Pf`, width, height, scale)".into(),
            ));
        }
        tokens.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    if pos >= bytes.len() || !bytes[pos].is_ascii_whitespace() {
        return Err(bad(
            "malformed PFM header: no line break after the scale".into()
        ));
    }
    pos += 1;

    let channels = match tokens[0].as_str() {
        "Pf" => 1,
        "PF" => 3,
        t => {
            return Err(bad(format!(
                "not a PFM file: magic is `{t}`, expected `PF` or `Pf`"
            )))
        }
    };
    let dim = |t: &str, what: &str| {
        t.parse::<usize>()
            .map_err(|_| bad(format!("PFM {what} `{t}` is not a non-negative integer")))
    };
    let width = dim(&tokens[1], "width")?;
    let height = dim(&tokens[2], "height")?;
    let scale: f64 = tokens[3]
        .parse()
        .map_err(|_| bad(format!("PFM scale `{}` is not a number", tokens[3])))?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(bad(format!(
            "PFM scale must be non-zero and finite (its sign is the byte order), got {scale}"
        )));
    }
    let little = scale < 0.0;

    let row_len = width
        .checked_mul(channels)
        .ok_or_else(|| bad("PFM size overflows".into()))?;
    let count = row_len
        .checked_mul(height)
        .ok_or_else(|| bad("PFM size overflows".into()))?;
    let need = count
        .checked_mul(4)
        .ok_or_else(|| bad("PFM size overflows".into()))?;
    let have = bytes.len() - pos;
    if have < need {
        return Err(bad(format!(
            "truncated PFM: a {width}x{height} map with {channels} channel(s) needs {need} data bytes, the file has {have}"
        )));
    }

    let body = &bytes[pos..pos + need];
    let mut data = vec![0f32; count];
    for (file_row, chunk) in body
        .chunks_exact((row_len * 4).max(1))
        .take(height)
        .enumerate()
    {
        let y = height - 1 - file_row;
        let out = &mut data[y * row_len..(y + 1) * row_len];
        for (v, b) in out.iter_mut().zip(chunk.chunks_exact(4)) {
            let b = [b[0], b[1], b[2], b[3]];
            *v = if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(FloatMap {
        width,
        height,
        channels,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize, c: usize) -> FloatMap {
        let data = (0..w * h * c).map(|i| i as f32 * 0.37 - 5.0).collect();
        FloatMap {
            width: w,
            height: h,
            channels: c,
            data,
        }
    }

    #[test]
    fn round_trips_one_and_three_channels() {
        let dir = tempfile::tempdir().unwrap();
        for c in [1, 3] {
            let mut m = ramp(7, 5, c);
            m.data[3] = f32::NAN;
            m.data[4] = f32::INFINITY;
            let p = dir.path().join(format!("m{c}.pfm"));
            write_pfm(&p, &m).unwrap();
            let back = read_pfm(&p).unwrap();
            assert_eq!((back.width, back.height, back.channels), (7, 5, c));
            let bits = |m: &FloatMap| m.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&back), bits(&m));
        }
    }

    #[test]
    fn rows_are_stored_bottom_to_top() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.pfm");
        let m = FloatMap {
            width: 1,
            height: 2,
            channels: 1,
            data: vec![1.0, 2.0],
        };
        write_pfm(&p, &m).unwrap();
        let bytes = fs::read(&p).unwrap();
        assert!(bytes.starts_with(b"Pf\n1 2\n-1\n"));
        assert_eq!(
            &bytes[bytes.len() - 8..],
            [2f32.to_le_bytes(), 1f32.to_le_bytes()].concat().as_slice()
        );
    }

    #[test]
    fn reads_big_endian() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("be.pfm");
        let mut bytes = b"PF\n1 1\n1.0\n".to_vec();
        for v in [1.5f32, -2.0, 3.25] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        fs::write(&p, bytes).unwrap();
        assert_eq!(read_pfm(&p).unwrap().data, vec![1.5, -2.0, 3.25]);
    }

    #[test]
    fn truncated_and_malformed_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.pfm");
        write_pfm(&p, &ramp(4, 3, 3)).unwrap();
        let good = fs::read(&p).unwrap();
        for cut in [0, 2, 6, 10, good.len() - 1] {
            fs::write(&p, &good[..cut]).unwrap();
            let e = read_pfm(&p).unwrap_err().to_string();
            assert!(
                e.contains("t.pfm") && (e.contains("truncated") || e.contains("header")),
                "{cut}: {e}"
            );
        }
        fs::write(&p, &good[..good.len() - 1]).unwrap();
        assert!(read_pfm(&p)
            .unwrap_err()
            .to_string()
            .contains("truncated PFM"));
        for bad in [
            &b"P6\n1 1\n-1\n\0\0\0\0"[..],
            b"Pf\n-1 1\n-1\n\0\0\0\0",
            b"Pf\n1 1\n0\n\0\0\0\0",
            b"Pf\n99999999999 99999999999\n-1\n",
        ] {
            fs::write(&p, bad).unwrap();
            assert!(matches!(read_pfm(&p), Err(IoError::Format { .. })));
        }
        let bad_map = FloatMap {
            width: 2,
            height: 2,
            channels: 2,
            data: vec![0.0; 8],
        };
        assert!(matches!(
            write_pfm(&p, &bad_map),
            Err(IoError::Input { .. })
        ));
    }
}
