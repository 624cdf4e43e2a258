//! A compact binary file for the features of one image (`features/<index>.feat`), so the match stage
//! reloads full-precision descriptors without decoding images again.
//!
//! Layout (little-endian): magic `HHFEAT01`, `u64` keypoint count `n`, `u64` descriptor dimension
//! `d`, then `n × 5` `f32` (x, y, scale, orientation, response), then `n × d` `f32` descriptors.
//! With the keypoints' colours, the magic is `HHFEAT02` and `n × 3` bytes (RGB at each keypoint)
//! follow, so the sparse stage colours its points without decoding the images again.

use std::path::Path;

use crate::atomic::write_atomic;
use crate::error::{IoError, Result};

const MAGIC: &[u8; 8] = b"HHFEAT01";
const MAGIC_COLOURS: &[u8; 8] = b"HHFEAT02";

/// The features of one image as stored on disk.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FeatureFile {
    /// `(x, y, scale, orientation, response)` per keypoint, Handheld pixel convention.
    pub keypoints: Vec<[f32; 5]>,
    pub dim: usize,
    /// Row-major `keypoints.len() × dim`.
    pub descriptors: Vec<f32>,
    /// RGB of the image at each keypoint; empty when not recorded.
    pub colors: Vec<[u8; 3]>,
}

/// Writes a feature file atomically.
pub fn write_features(path: &Path, f: &FeatureFile) -> Result<()> {
    if f.descriptors.len() != f.keypoints.len() * f.dim {
        return Err(IoError::format(
            path,
            "descriptor count does not match keypoint count",
        ));
    }
    if !f.colors.is_empty() && f.colors.len() != f.keypoints.len() {
        return Err(IoError::format(
            path,
            "colour count does not match keypoint count",
        ));
    }
    write_atomic(path, |w| {
        w.write_all(if f.colors.is_empty() {
            MAGIC
        } else {
            MAGIC_COLOURS
        })?;
        w.write_all(&(f.keypoints.len() as u64).to_le_bytes())?;
        w.write_all(&(f.dim as u64).to_le_bytes())?;
        let mut buf = Vec::with_capacity(f.keypoints.len() * 20 + f.descriptors.len() * 4);
        for k in &f.keypoints {
            for v in k {
                buf.extend_from_slice(&v.to_le_bytes());
            }
        }
        for v in &f.descriptors {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        for c in &f.colors {
            buf.extend_from_slice(c);
        }
        w.write_all(&buf)
    })
}

/// Reads a feature file; truncated or foreign files are errors naming the path.
pub fn read_features(path: &Path) -> Result<FeatureFile> {
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, e))?;
    if bytes.len() < 24 || (&bytes[..8] != MAGIC && &bytes[..8] != MAGIC_COLOURS) {
        return Err(IoError::format(path, "not a Handheld feature file"));
    }
    let with_colours = &bytes[..8] == MAGIC_COLOURS;
    let u64_at = |o: usize| {
        u64::from_le_bytes([
            bytes[o],
            bytes[o + 1],
            bytes[o + 2],
            bytes[o + 3],
            bytes[o + 4],
            bytes[o + 5],
            bytes[o + 6],
            bytes[o + 7],
        ])
    };
    let (n, d) = (u64_at(8) as usize, u64_at(16) as usize);
    let floats_end = n
        .checked_mul(5 + d)
        .and_then(|c| c.checked_mul(4))
        .and_then(|c| c.checked_add(24));
    let need = floats_end.and_then(|e| e.checked_add(if with_colours { 3 * n } else { 0 }));
    if need != Some(bytes.len()) {
        return Err(IoError::format(
            path,
            format!(
                "truncated or corrupt: {n} keypoints × {d} need {need:?} bytes, file has {}",
                bytes.len()
            ),
        ));
    }
    let floats_end = floats_end.unwrap_or(24);
    let floats: Vec<f32> = bytes[24..floats_end]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let keypoints = floats[..5 * n]
        .chunks_exact(5)
        .map(|c| [c[0], c[1], c[2], c[3], c[4]])
        .collect();
    let colors = bytes[floats_end..]
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Ok(FeatureFile {
        keypoints,
        dim: d,
        descriptors: floats[5 * n..].to_vec(),
        colors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_truncation() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("0.feat");
        let f = FeatureFile {
            keypoints: vec![[1.0, 2.0, 3.0, 0.5, 9.0], [4.0, 5.0, 1.0, -1.0, 2.0]],
            dim: 3,
            descriptors: vec![0.1, 0.2, 0.3, 0.4, 0.5, 0.6],
            colors: Vec::new(),
        };
        write_features(&p, &f).unwrap();
        assert_eq!(read_features(&p).unwrap(), f);
        let coloured = FeatureFile {
            colors: vec![[1, 2, 3], [250, 251, 252]],
            ..f.clone()
        };
        write_features(&p, &coloured).unwrap();
        assert_eq!(read_features(&p).unwrap(), coloured);
        let wrong = FeatureFile {
            colors: vec![[1, 2, 3]],
            ..f.clone()
        };
        assert!(write_features(&p, &wrong).is_err());
        write_features(&p, &f).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 3]).unwrap();
        let err = read_features(&p).unwrap_err().to_string();
        assert!(err.contains("0.feat") && err.contains("truncated"), "{err}");
    }
}
