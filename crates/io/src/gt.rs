//! Ground-truth cameras of the public data sets in `../shared/datasets` (formats in its README),
//! as projection matrices keyed by image file stem: Strecha `.camera` files (`P = K [Rᵀ | −Rᵀ C]`)
//! and Middlebury `*_par.txt` (`P = K [R | t]`).

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::{Matrix3, Matrix3x4, Vector3};

use crate::error::{IoError, Result};

/// A ground-truth camera: `P = K [R | t]` with `R, t` world→camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GtCamera {
    pub k: Matrix3<f64>,
    pub r_cam_from_world: Matrix3<f64>,
    pub t: Vector3<f64>,
}

impl GtCamera {
    pub fn projection(&self) -> Matrix3x4<f64> {
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.r_cam_from_world);
        rt.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.t);
        self.k * rt
    }

    pub fn center(&self) -> Vector3<f64> {
        -(self.r_cam_from_world.transpose() * self.t)
    }
}

fn numbers(path: &Path) -> Result<Vec<f64>> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::io(path, e))?;
    text.split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .map_err(|_| IoError::format(path, format!("not a number: {t:?}")))
        })
        .collect()
}

/// Reads every ground-truth camera of a data set folder (`DATASET/gt/…`), keyed by image stem
/// (`0003` for `0003.jpg`).
pub fn read_gt_cameras(dataset: &Path) -> Result<BTreeMap<String, GtCamera>> {
    let gt = dataset.join("gt");
    let entries = std::fs::read_dir(&gt).map_err(|e| IoError::io(&gt, e))?;
    let mut out = BTreeMap::new();
    let mut par = None;
    for e in entries.flatten() {
        let p = e.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.ends_with(".camera") {
            let v = numbers(&p)?;
            if v.len() < 24 {
                return Err(IoError::format(
                    &p,
                    "a Strecha camera file needs at least 24 numbers",
                ));
            }
            let k = Matrix3::from_row_slice(&v[0..9]);
            let r_world_from_cam = Matrix3::from_row_slice(&v[12..21]);
            let c = Vector3::new(v[21], v[22], v[23]);
            let r = r_world_from_cam.transpose();
            let stem = name.split('.').next().unwrap_or_default().to_string();
            out.insert(
                stem,
                GtCamera {
                    k,
                    r_cam_from_world: r,
                    t: -(r * c),
                },
            );
        } else if name.ends_with("_par.txt") {
            par = Some(p);
        }
    }
    if let Some(p) = par.filter(|_| out.is_empty()) {
        let text = std::fs::read_to_string(&p).map_err(|e| IoError::io(&p, e))?;
        for (i, line) in text.lines().skip(1).enumerate() {
            let t: Vec<&str> = line.split_whitespace().collect();
            if t.is_empty() {
                continue;
            }
            if t.len() < 22 {
                return Err(IoError::format(
                    &p,
                    format!("line {}: expected a name and 21 numbers", i + 2),
                ));
            }
            let v: Vec<f64> = t[1..22]
                .iter()
                .map(|s| {
                    s.parse().map_err(|_| {
                        IoError::format(&p, format!("line {}: bad number {s:?}", i + 2))
                    })
                })
                .collect::<Result<_>>()?;
            let stem = t[0].split('.').next().unwrap_or_default().to_string();
            out.insert(
                stem,
                GtCamera {
                    k: Matrix3::from_row_slice(&v[0..9]),
                    r_cam_from_world: Matrix3::from_row_slice(&v[9..18]),
                    t: Vector3::new(v[18], v[19], v[20]),
                },
            );
        }
    }
    if out.is_empty() {
        return Err(IoError::format(
            &gt,
            "no ground-truth cameras found (.camera or *_par.txt)",
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strecha_camera_projects_its_centre_to_nothing() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("gt")).unwrap();
        std::fs::write(
            dir.path().join("gt/0000.jpg.camera"),
            "2759.48 0 1520.69\n0 2764.16 1006.81\n0 0 1\n0 0 0\n0.450927 -0.0945642 -0.887537\n-0.892535 -0.0401974 -0.449183\n0.00679989 0.994707 -0.102528\n-7.28137 -7.57667 0.204446\n3072 2048\n",
        )
        .unwrap();
        let cams = read_gt_cameras(dir.path()).unwrap();
        let c = cams["0000"];
        let p = c.projection();
        let file_centre = Vector3::new(-7.28137, -7.57667, 0.204446);
        assert!((p * file_centre.push(1.0)).norm() < 1e-9 * p.norm());
        // The stored rotation has 6 digits, so Rᵀ R ≈ I only to ~1e-6.
        assert!((c.center() - file_centre).norm() < 1e-4);
    }
}
