//! COLMAP's binary model: `cameras.bin`, `images.bin` and `points3D.bin`, little-endian, laid out
//! exactly as COLMAP's `Write*Binary` functions do. Readers check every length against the bytes
//! left, so a truncated or corrupt file is an [`IoError::Format`] naming the file and byte offset.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;

use super::{
    check_params, CameraModel, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint2D, ColmapPoint3D,
};
use crate::atomic::write_atomic;
use crate::error::{IoError, Result};

/// COLMAP's `kInvalidPoint3DId` (written as `-1` in text).
const INVALID_POINT3D_ID: u64 = u64::MAX;

/// Writes `cameras.bin`, `images.bin` and `points3D.bin` into `dir` (created if needed), each atomically.
pub fn write_binary(dir: &Path, m: &ColmapModel) -> Result<()> {
    let cam_path = dir.join("cameras.bin");
    for c in m.cameras.values() {
        check_params(c).map_err(|reason| IoError::Input {
            path: cam_path.clone(),
            reason,
        })?;
    }
    let img_path = dir.join("images.bin");
    for im in m.images.values() {
        if im.name.contains('\0') {
            return Err(IoError::Input {
                path: img_path,
                reason: format!("image {}: name contains a NUL byte", im.id),
            });
        }
        if im
            .points2d
            .iter()
            .any(|p| p.point3d_id == Some(INVALID_POINT3D_ID))
        {
            return Err(IoError::Input {
                path: img_path,
                reason: format!(
                    "image {}: point id {INVALID_POINT3D_ID} is COLMAP's 'no point' marker",
                    im.id
                ),
            });
        }
    }

    write_atomic(&cam_path, |w| {
        w.write_all(&(m.cameras.len() as u64).to_le_bytes())?;
        for c in m.cameras.values() {
            w.write_all(&c.id.to_le_bytes())?;
            w.write_all(&c.model.id().to_le_bytes())?;
            w.write_all(&c.width.to_le_bytes())?;
            w.write_all(&c.height.to_le_bytes())?;
            for p in &c.params {
                w.write_all(&p.to_le_bytes())?;
            }
        }
        Ok(())
    })?;

    write_atomic(&img_path, |w| {
        w.write_all(&(m.images.len() as u64).to_le_bytes())?;
        for im in m.images.values() {
            w.write_all(&im.id.to_le_bytes())?;
            for v in im.qvec.iter().chain(&im.tvec) {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&im.camera_id.to_le_bytes())?;
            w.write_all(im.name.as_bytes())?;
            w.write_all(&[0])?;
            w.write_all(&(im.points2d.len() as u64).to_le_bytes())?;
            for p in &im.points2d {
                w.write_all(&p.x.to_le_bytes())?;
                w.write_all(&p.y.to_le_bytes())?;
                w.write_all(&p.point3d_id.unwrap_or(INVALID_POINT3D_ID).to_le_bytes())?;
            }
        }
        Ok(())
    })?;

    write_atomic(&dir.join("points3D.bin"), |w| {
        w.write_all(&(m.points3d.len() as u64).to_le_bytes())?;
        for p in m.points3d.values() {
            w.write_all(&p.id.to_le_bytes())?;
            for v in &p.xyz {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&p.rgb)?;
            w.write_all(&p.error.to_le_bytes())?;
            w.write_all(&(p.track.len() as u64).to_le_bytes())?;
            for (img, idx) in &p.track {
                w.write_all(&img.to_le_bytes())?;
                w.write_all(&idx.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Reads `cameras.bin`, `images.bin` and `points3D.bin` from `dir`.
pub fn read_binary(dir: &Path) -> Result<ColmapModel> {
    Ok(ColmapModel {
        cameras: read_cameras(&dir.join("cameras.bin"))?,
        images: read_images(&dir.join("images.bin"))?,
        points3d: read_points(&dir.join("points3D.bin"))?,
    })
}

/// A bounds-checked little-endian reader over a whole file.
struct Cursor<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn err(&self, reason: impl std::fmt::Display) -> IoError {
        IoError::format(self.path, format!("byte {}: {reason}", self.pos))
    }

    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let end = self.pos.checked_add(N).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(self.err(format!("file is truncated while reading {what}")));
        };
        let mut out = [0u8; N];
        out.copy_from_slice(&self.data[self.pos..end]);
        self.pos = end;
        Ok(out)
    }

    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take::<1>(what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        self.take(what).map(u32::from_le_bytes)
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        self.take(what).map(i32::from_le_bytes)
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        self.take(what).map(u64::from_le_bytes)
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        self.take(what).map(f64::from_le_bytes)
    }

    /// A record count, checked against the bytes left (each record takes at least `min_size` bytes).
    fn count(&mut self, what: &str, min_size: usize) -> Result<usize> {
        let n = self.u64(what)?;
        let left = (self.data.len() - self.pos) as u64;
        let fits = matches!(n.checked_mul(min_size as u64), Some(need) if need <= left);
        if !fits {
            return Err(self.err(format!("{what} is {n}, more than the {left} bytes left can hold (truncated or corrupt file)")));
        }
        Ok(n as usize)
    }

    fn c_string(&mut self, what: &str) -> Result<String> {
        let rest = &self.data[self.pos..];
        let Some(len) = rest.iter().position(|&b| b == 0) else {
            return Err(self.err(format!(
                "file is truncated inside {what} (no terminating NUL)"
            )));
        };
        let s = std::str::from_utf8(&rest[..len])
            .map_err(|_| self.err(format!("{what} is not valid UTF-8")))?;
        self.pos += len + 1;
        Ok(s.to_string())
    }

    fn finish(&self) -> Result<()> {
        if self.pos != self.data.len() {
            return Err(self.err(format!(
                "{} unexpected trailing bytes",
                self.data.len() - self.pos
            )));
        }
        Ok(())
    }
}

fn read_cameras(path: &Path) -> Result<BTreeMap<u32, ColmapCamera>> {
    let data = fs::read(path).map_err(|e| IoError::io(path, e))?;
    let mut c = Cursor {
        path,
        data: &data,
        pos: 0,
    };
    let n = c.count("number of cameras", 4 + 4 + 8 + 8)?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let id = c.u32("CAMERA_ID")?;
        let model_id = c.i32("model id")?;
        let model = CameraModel::from_id(model_id).ok_or_else(|| {
            c.err(format!(
                "camera {id}: unsupported camera model id {model_id} (supported: 0 SIMPLE_PINHOLE, 1 PINHOLE, 2 SIMPLE_RADIAL, 3 RADIAL, 4 OPENCV)"
            ))
        })?;
        let width = c.u64("WIDTH")?;
        let height = c.u64("HEIGHT")?;
        let params = (0..model.num_params())
            .map(|_| c.f64("camera parameter"))
            .collect::<Result<Vec<_>>>()?;
        if out
            .insert(
                id,
                ColmapCamera {
                    id,
                    model,
                    width,
                    height,
                    params,
                },
            )
            .is_some()
        {
            return Err(c.err(format!("duplicate CAMERA_ID {id}")));
        }
    }
    c.finish()?;
    Ok(out)
}

fn read_images(path: &Path) -> Result<BTreeMap<u32, ColmapImage>> {
    let data = fs::read(path).map_err(|e| IoError::io(path, e))?;
    let mut c = Cursor {
        path,
        data: &data,
        pos: 0,
    };
    let n = c.count("number of images", 4 + 7 * 8 + 4 + 1 + 8)?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let id = c.u32("IMAGE_ID")?;
        let qvec = [c.f64("QW")?, c.f64("QX")?, c.f64("QY")?, c.f64("QZ")?];
        let tvec = [c.f64("TX")?, c.f64("TY")?, c.f64("TZ")?];
        let camera_id = c.u32("CAMERA_ID")?;
        let name = c.c_string("NAME")?;
        let np = c.count("number of keypoints", 24)?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            let x = c.f64("X")?;
            let y = c.f64("Y")?;
            let id = c.u64("POINT3D_ID")?;
            points2d.push(ColmapPoint2D {
                x,
                y,
                point3d_id: (id != INVALID_POINT3D_ID).then_some(id),
            });
        }
        if out
            .insert(
                id,
                ColmapImage {
                    id,
                    qvec,
                    tvec,
                    camera_id,
                    name,
                    points2d,
                },
            )
            .is_some()
        {
            return Err(c.err(format!("duplicate IMAGE_ID {id}")));
        }
    }
    c.finish()?;
    Ok(out)
}

fn read_points(path: &Path) -> Result<BTreeMap<u64, ColmapPoint3D>> {
    let data = fs::read(path).map_err(|e| IoError::io(path, e))?;
    let mut c = Cursor {
        path,
        data: &data,
        pos: 0,
    };
    let n = c.count("number of points", 8 + 3 * 8 + 3 + 8 + 8)?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let id = c.u64("POINT3D_ID")?;
        let xyz = [c.f64("X")?, c.f64("Y")?, c.f64("Z")?];
        let rgb = [c.u8("R")?, c.u8("G")?, c.u8("B")?];
        let error = c.f64("ERROR")?;
        let len = c.count("track length", 8)?;
        let track = (0..len)
            .map(|_| Ok((c.u32("IMAGE_ID")?, c.u32("POINT2D_IDX")?)))
            .collect::<Result<Vec<_>>>()?;
        if out
            .insert(
                id,
                ColmapPoint3D {
                    id,
                    xyz,
                    rgb,
                    error,
                    track,
                },
            )
            .is_some()
        {
            return Err(c.err(format!("duplicate POINT3D_ID {id}")));
        }
    }
    c.finish()?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::testdata::sample_model;
    use super::*;

    #[test]
    fn binary_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let m = sample_model();
        write_binary(dir.path(), &m).unwrap();
        assert_eq!(read_binary(dir.path()).unwrap(), m);
    }

    #[test]
    fn layout_matches_colmap() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = ColmapModel::default();
        m.cameras.insert(
            3,
            ColmapCamera {
                id: 3,
                model: CameraModel::SimplePinhole,
                width: 64,
                height: 48,
                params: vec![1.0, 2.0, 3.0],
            },
        );
        m.images.insert(
            9,
            ColmapImage {
                id: 9,
                qvec: [1.0, 0.0, 0.0, 0.0],
                tvec: [0.0; 3],
                camera_id: 3,
                name: "ab".into(),
                points2d: vec![ColmapPoint2D {
                    x: 0.5,
                    y: 1.5,
                    point3d_id: None,
                }],
            },
        );
        write_binary(dir.path(), &m).unwrap();
        let cams = fs::read(dir.path().join("cameras.bin")).unwrap();
        assert_eq!(cams.len(), 8 + 4 + 4 + 8 + 8 + 3 * 8);
        assert_eq!(&cams[8..16], &[3, 0, 0, 0, 0, 0, 0, 0]);
        let imgs = fs::read(dir.path().join("images.bin")).unwrap();
        assert_eq!(imgs.len(), 8 + 4 + 56 + 4 + 3 + 8 + 24);
        assert_eq!(&imgs[72..75], b"ab\0");
        assert_eq!(&imgs[imgs.len() - 8..], &[0xff; 8]);
        let pts = fs::read(dir.path().join("points3D.bin")).unwrap();
        assert_eq!(pts, vec![0; 8]);
    }

    #[test]
    fn truncated_and_corrupt_files_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        write_binary(d, &sample_model()).unwrap();
        for file in ["cameras.bin", "images.bin", "points3D.bin"] {
            let good = fs::read(d.join(file)).unwrap();
            for cut in [0, 5, 8, 13, good.len() / 2, good.len() - 1] {
                fs::write(d.join(file), &good[..cut]).unwrap();
                let e = read_binary(d).unwrap_err().to_string();
                assert!(
                    e.contains(file) && e.contains("byte"),
                    "{file} cut at {cut}: {e}"
                );
            }
            let mut huge = good.clone();
            huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
            fs::write(d.join(file), &huge).unwrap();
            assert!(read_binary(d)
                .unwrap_err()
                .to_string()
                .contains("truncated or corrupt"));
            fs::write(d.join(file), &good).unwrap();
        }
        let mut cams = fs::read(d.join("cameras.bin")).unwrap();
        cams[12] = 11; // model id of the first camera
        fs::write(d.join("cameras.bin"), &cams).unwrap();
        let e = read_binary(d).unwrap_err().to_string();
        assert!(e.contains("unsupported camera model id 11"), "{e}");
    }
}
