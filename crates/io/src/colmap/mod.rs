//! COLMAP sparse models (`cameras`, `images`, `points3D`), in COLMAP's own text and binary formats.
//!
//! [`ColmapModel`] is a raw, lossless image of what the files hold; [`text`] and [`binary`] read and
//! write it exactly as COLMAP does (text floats use Rust's shortest round-trip formatting, so a text
//! round trip is bit-exact). [`convert`] maps it to and from Handheld's [`MetricReconstruction`],
//! shifting pixel coordinates by [`handheld_core::PIXEL_CENTER_OFFSET_COLMAP`] at the boundary.

use std::collections::BTreeMap;
use std::path::Path;

use handheld_core::MetricReconstruction;

use crate::error::{IoError, Result};

pub mod binary;
pub mod convert;
pub mod text;

pub use binary::{read_binary, write_binary};
pub use convert::{camera_to_colmap, from_colmap, to_colmap};
pub use text::{read_text, write_text};

/// The COLMAP camera models Handheld reads and writes (ids and names as in COLMAP).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CameraModel {
    /// `f, cx, cy`.
    SimplePinhole = 0,
    /// `fx, fy, cx, cy`.
    Pinhole = 1,
    /// `f, cx, cy, k`.
    SimpleRadial = 2,
    /// `f, cx, cy, k1, k2`.
    Radial = 3,
    /// `fx, fy, cx, cy, k1, k2, p1, p2`.
    Opencv = 4,
}

impl CameraModel {
    /// Every supported model, in id order.
    pub const ALL: [CameraModel; 5] = [
        CameraModel::SimplePinhole,
        CameraModel::Pinhole,
        CameraModel::SimpleRadial,
        CameraModel::Radial,
        CameraModel::Opencv,
    ];

    /// COLMAP's numeric model id (as stored in `cameras.bin`).
    pub fn id(self) -> i32 {
        self as i32
    }

    /// The model with a numeric id, if supported.
    pub fn from_id(id: i32) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.id() == id)
    }

    /// COLMAP's model name (as written in `cameras.txt`).
    pub fn name(self) -> &'static str {
        match self {
            CameraModel::SimplePinhole => "SIMPLE_PINHOLE",
            CameraModel::Pinhole => "PINHOLE",
            CameraModel::SimpleRadial => "SIMPLE_RADIAL",
            CameraModel::Radial => "RADIAL",
            CameraModel::Opencv => "OPENCV",
        }
    }

    /// The model with a name, if supported.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Number of parameters COLMAP stores for the model.
    pub fn num_params(self) -> usize {
        match self {
            CameraModel::SimplePinhole => 3,
            CameraModel::Pinhole => 4,
            CameraModel::SimpleRadial => 4,
            CameraModel::Radial => 5,
            CameraModel::Opencv => 8,
        }
    }
}

/// One COLMAP camera (intrinsics group). Parameters are in COLMAP's pixel convention.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// `CAMERA_ID`.
    pub id: u32,
    /// `MODEL`.
    pub model: CameraModel,
    /// `WIDTH` in pixels.
    pub width: u64,
    /// `HEIGHT` in pixels.
    pub height: u64,
    /// `PARAMS[]`, [`CameraModel::num_params`] of them.
    pub params: Vec<f64>,
}

/// A keypoint of a COLMAP image, in COLMAP's pixel convention (top-left pixel centre at `(0.5, 0.5)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColmapPoint2D {
    /// `X`.
    pub x: f64,
    /// `Y`.
    pub y: f64,
    /// `POINT3D_ID`; `None` is stored as `-1`.
    pub point3d_id: Option<u64>,
}

/// One COLMAP image: its pose `cam_from_world` and its keypoints.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// `IMAGE_ID`.
    pub id: u32,
    /// Rotation `cam_from_world` as a quaternion `(w, x, y, z)`.
    pub qvec: [f64; 4],
    /// Translation of `cam_from_world`.
    pub tvec: [f64; 3],
    /// `CAMERA_ID`.
    pub camera_id: u32,
    /// `NAME`, relative to the image folder.
    pub name: String,
    /// `POINTS2D[]`.
    pub points2d: Vec<ColmapPoint2D>,
}

/// One COLMAP 3D point with its track of `(IMAGE_ID, POINT2D_IDX)` pairs.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint3D {
    /// `POINT3D_ID`.
    pub id: u64,
    /// `X, Y, Z`.
    pub xyz: [f64; 3],
    /// `R, G, B`.
    pub rgb: [u8; 3],
    /// `ERROR`: mean reprojection error in pixels.
    pub error: f64,
    /// `TRACK[]` as `(IMAGE_ID, POINT2D_IDX)`.
    pub track: Vec<(u32, u32)>,
}

/// A COLMAP sparse model, keyed by id exactly as the files store it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// `cameras.txt` / `cameras.bin`.
    pub cameras: BTreeMap<u32, ColmapCamera>,
    /// `images.txt` / `images.bin`.
    pub images: BTreeMap<u32, ColmapImage>,
    /// `points3D.txt` / `points3D.bin`.
    pub points3d: BTreeMap<u64, ColmapPoint3D>,
}

/// Checks that a camera has as many parameters as its model needs (used by the writers and readers).
pub(crate) fn check_params(c: &ColmapCamera) -> std::result::Result<(), String> {
    if c.params.len() != c.model.num_params() {
        return Err(format!(
            "camera {}: model {} needs {} parameters, found {}",
            c.id,
            c.model.name(),
            c.model.num_params(),
            c.params.len()
        ));
    }
    Ok(())
}

/// Reads a model from `dir`: binary when `cameras.bin` exists, text otherwise.
pub fn read_model(dir: &Path) -> Result<ColmapModel> {
    if dir.join("cameras.bin").is_file() {
        read_binary(dir)
    } else {
        read_text(dir)
    }
}

/// Converts `rec` with [`to_colmap`] and writes it to `dir` as text and/or binary (both may coexist).
pub fn write_reconstruction(
    dir: &Path,
    rec: &MetricReconstruction,
    text: bool,
    binary: bool,
) -> Result<()> {
    let model = to_colmap(rec).map_err(|reason| IoError::Input {
        path: dir.to_path_buf(),
        reason,
    })?;
    if text {
        write_text(dir, &model)?;
    }
    if binary {
        write_binary(dir, &model)?;
    }
    Ok(())
}

/// Reads a model with [`read_model`] and converts it with [`from_colmap`].
pub fn read_reconstruction(dir: &Path) -> Result<MetricReconstruction> {
    let model = read_model(dir)?;
    from_colmap(&model).map_err(|reason| IoError::format(dir, reason))
}

#[cfg(test)]
pub(crate) mod testdata {
    use super::*;

    /// A model with every camera model, images with and without keypoints and long tracks.
    pub fn sample_model() -> ColmapModel {
        let mut m = ColmapModel::default();
        let params: [&[f64]; 5] = [
            &[1234.5678901234567, 320.5, 240.5],
            &[800.125, 801.0000000000001, 319.75, 239.25],
            &[500.0, 320.0, 240.0, -0.123456789e-3],
            &[650.3, 321.1, 241.9, 0.1, -0.0123],
            &[
                1.0e3 / 3.0,
                2.0e3 / 7.0,
                0.1 + 0.2,
                -0.0,
                1e-300,
                -7.5e12,
                0.001,
                -0.002,
            ],
        ];
        for (i, model) in CameraModel::ALL.into_iter().enumerate() {
            let id = i as u32 + 1;
            m.cameras.insert(
                id,
                ColmapCamera {
                    id,
                    model,
                    width: 640 + i as u64,
                    height: 480,
                    params: params[i].to_vec(),
                },
            );
        }
        for id in 1..=6u32 {
            let n = if id == 3 { 0 } else { 40 + id as usize };
            let points2d = (0..n)
                .map(|k| ColmapPoint2D {
                    x: k as f64 * 1.1 + 0.1 * id as f64,
                    y: 479.9 - k as f64 / 3.0,
                    point3d_id: if k % 3 == 0 {
                        None
                    } else {
                        Some(k as u64 + 100)
                    },
                })
                .collect();
            let q = [0.5f64.sqrt(), 0.1 * id as f64, -0.2, 1.0 / 3.0];
            m.images.insert(
                id,
                ColmapImage {
                    id,
                    qvec: q,
                    tvec: [id as f64 * 0.7, -1.0 / 7.0, 12.25],
                    camera_id: (id - 1) % 5 + 1,
                    name: format!("frames/img_{id:04}.jpg"),
                    points2d,
                },
            );
        }
        for id in [100u64, 101, 5_000_000_000, u64::MAX - 1] {
            let len = (id % 97) as u32 + 2;
            m.points3d.insert(
                id,
                ColmapPoint3D {
                    id,
                    xyz: [id as f64 * 1e-3, -2.5, std::f64::consts::PI],
                    rgb: [255, 0, (id % 256) as u8],
                    error: 0.37 + id as f64 * 1e-9,
                    track: (0..len).map(|k| (k % 6 + 1, k * 7)).collect(),
                },
            );
        }
        m
    }

    #[test]
    fn model_ids_and_names_round_trip() {
        for m in CameraModel::ALL {
            assert_eq!(CameraModel::from_id(m.id()), Some(m));
            assert_eq!(CameraModel::from_name(m.name()), Some(m));
        }
        assert_eq!(CameraModel::from_id(5), None);
        assert_eq!(CameraModel::from_name("FULL_OPENCV"), None);
    }

    #[test]
    fn read_model_prefers_binary() {
        let dir = tempfile::tempdir().unwrap();
        let m = sample_model();
        write_text(dir.path(), &m).unwrap();
        assert_eq!(read_model(dir.path()).unwrap(), m);
        let mut m2 = m.clone();
        m2.points3d.clear();
        write_binary(dir.path(), &m2).unwrap();
        assert_eq!(read_model(dir.path()).unwrap(), m2);
    }
}
