//! A workspace from Python: each stage's summary, the sparse model, the depth maps and the mesh as
//! numpy arrays. The files are read by `handheld-io`'s readers, as the pipeline reads them; the
//! arrays take the readers' buffers without a copy where their layout is already numpy's.
//!
//! Conventions follow pycolmap: poses are `cam_from_world` (`x_cam = R x_world + t`), quaternions
//! are `(x, y, z, w)`, camera parameters and keypoints are in COLMAP's pixel convention (the centre
//! of the top-left pixel at `(0.5, 0.5)`), cameras are COLMAP models by name.

use std::path::{Path, PathBuf};

use handheld_io::colmap::{CameraModel, ColmapCamera, ColmapModel};
use handheld_io::dense_folder::{map_file, read_cameras, MapKind};
use handheld_pipeline::files::{self, stage};
use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::{message, HandheldError};

fn io_err(e: handheld_io::IoError) -> PyErr {
    HandheldError::new_err(message(e))
}

fn json_to_py<'py>(py: Python<'py>, v: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    pythonize::pythonize(py, v).map_err(|e| HandheldError::new_err(e.to_string()))
}

/// `(n, k)` array from rows (moved, not copied, into numpy).
fn rows<T: numpy::Element + Copy, const K: usize>(
    py: Python<'_>,
    r: Vec<[T; K]>,
) -> Bound<'_, PyArray2<T>> {
    let n = r.len();
    let flat: Vec<T> = r.into_iter().flatten().collect();
    Array2::from_shape_vec((n, K), flat)
        .expect("n rows of K")
        .into_pyarray(py)
}

/// A camera as pycolmap describes it: `model`, `width`, `height`, `params`, and `K` (3×3).
fn camera_dict<'py>(py: Python<'py>, c: &ColmapCamera) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("camera_id", c.id)?;
    d.set_item("model", c.model.name())?;
    d.set_item("width", c.width)?;
    d.set_item("height", c.height)?;
    d.set_item("params", c.params.clone().into_pyarray(py))?;
    d.set_item("K", calibration(c).into_pyarray(py))?;
    Ok(d)
}

/// The calibration matrix of a COLMAP camera (its first parameters are `f` or `fx, fy`, then
/// `cx, cy`, for every supported model).
fn calibration(c: &ColmapCamera) -> Array2<f64> {
    let p = &c.params;
    let (fx, fy, cx, cy) = match c.model {
        CameraModel::SimplePinhole | CameraModel::SimpleRadial | CameraModel::Radial => {
            (p[0], p[0], p[1], p[2])
        }
        CameraModel::Pinhole | CameraModel::Opencv => (p[0], p[1], p[2], p[3]),
    };
    Array2::from_shape_vec((3, 3), vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]).expect("3x3")
}

/// `R` (row-major) of a unit quaternion `(w, x, y, z)`.
fn rotation(q: [f64; 4]) -> [f64; 9] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

/// A Handheld workspace (the folder `handheld reconstruct -o` writes). Reading it changes nothing.
#[pyclass(frozen, module = "handheld")]
pub struct Workspace {
    root: PathBuf,
}

impl Workspace {
    fn ws(&self) -> handheld_pipeline::Workspace {
        handheld_pipeline::Workspace {
            root: self.root.clone(),
        }
    }

    fn dense_dir(&self) -> PathBuf {
        self.root.join(stage::DENSE)
    }
}

#[pymethods]
impl Workspace {
    /// Opens the workspace at `path`; raises `HandheldError` when it is not a folder.
    #[new]
    fn new(path: PathBuf) -> PyResult<Self> {
        if !path.is_dir() {
            return Err(HandheldError::new_err(format!(
                "{}: not a workspace folder (run handheld.reconstruct(input, workspace) first)",
                path.display()
            )));
        }
        Ok(Self { root: path })
    }

    /// The workspace folder.
    #[getter]
    fn path(&self) -> PathBuf {
        self.root.clone()
    }

    fn __repr__(&self) -> String {
        format!("handheld.Workspace('{}')", self.root.display())
    }

    /// The stages that have finished, in the graph's order.
    fn stages(&self) -> Vec<String> {
        let ws = self.ws();
        [
            stage::INGEST,
            stage::FEATURES,
            stage::MATCHES,
            stage::SPARSE,
            stage::DENSE,
            stage::MESH,
            stage::RENDER,
            stage::AUGMENT,
        ]
        .into_iter()
        .filter(|s| ws.manifest(s).is_some())
        .map(String::from)
        .collect()
    }

    /// The summary a finished stage recorded (a dict, as in its `manifest.json`), or None when the
    /// stage has not run.
    fn summary<'py>(&self, py: Python<'py>, stage: &str) -> PyResult<Option<Bound<'py, PyAny>>> {
        match self.ws().manifest(stage) {
            Some(m) => json_to_py(py, &m.summary).map(Some),
            None => Ok(None),
        }
    }

    /// The warnings a finished stage recorded (a list of dicts with `code`, `message`, `advice`).
    fn warnings<'py>(&self, py: Python<'py>, stage: &str) -> PyResult<Bound<'py, PyAny>> {
        let w = self
            .ws()
            .manifest(stage)
            .map(|m| m.warnings)
            .unwrap_or_default();
        json_to_py(py, &w)
    }

    /// Each stage's time in seconds (`timings.json`).
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &self.ws().timings())
    }

    /// The sparse model (`sparse/`, COLMAP binary or text) as numpy arrays.
    fn sparse(&self, py: Python<'_>) -> PyResult<SparseModel> {
        let dir = self.root.join(stage::SPARSE);
        let model = py
            .detach(|| handheld_io::colmap::read_model(&dir))
            .map_err(|e| {
                HandheldError::new_err(format!(
                    "{}: {} (run the sparse stage)",
                    dir.display(),
                    message(e)
                ))
            })?;
        SparseModel::from_colmap(py, &model)
    }

    /// The images the dense stage made depth maps for, in its order.
    fn depth_images(&self) -> PyResult<Vec<String>> {
        Ok(read_cameras(&self.dense_dir())
            .map_err(io_err)?
            .into_iter()
            .map(|e| e.image)
            .collect())
    }

    /// The dense stage's maps of one image: a dict with `depth` (H×W float32, camera-frame z,
    /// NaN where missing), `confidence`, `variance`, `visibility` (when written), and the camera
    /// they belong to (`camera`: model, width, height, params, K; `R`, `t`: cam_from_world). The
    /// maps may be smaller than the photo: the camera is scaled with them.
    fn depth<'py>(&self, py: Python<'py>, image: &str) -> PyResult<Bound<'py, PyDict>> {
        let dir = self.dense_dir();
        let entries = read_cameras(&dir).map_err(io_err)?;
        let Some(e) = entries.into_iter().find(|e| e.image == image) else {
            return Err(HandheldError::new_err(format!(
                "{}: no depth map for image `{image}` (see Workspace.depth_images())",
                dir.display()
            )));
        };
        let d = PyDict::new(py);
        for kind in MapKind::ALL {
            let path = dir.join(map_file(kind, &e.image));
            if kind != MapKind::Depth && !path.exists() {
                continue;
            }
            let map = py
                .detach(|| handheld_io::pfm::read_pfm(&path))
                .map_err(io_err)?;
            let shape = if map.channels == 1 {
                vec![map.height, map.width]
            } else {
                vec![map.height, map.width, map.channels]
            };
            let a = numpy::ndarray::ArrayD::from_shape_vec(shape, map.data)
                .map_err(|err| HandheldError::new_err(format!("{}: {err}", path.display())))?;
            d.set_item(kind.dir_name(), a.into_pyarray(py))?;
        }
        let cam = handheld_io::colmap::camera_to_colmap(&e.camera)
            .map_err(|err| HandheldError::new_err(format!("{}: {err}", dir.display())))?;
        d.set_item("camera", camera_dict(py, &cam)?)?;
        let q = e.cam_from_world.rotation;
        let r = rotation([q.w, q.i, q.j, q.k]);
        d.set_item(
            "R",
            Array2::from_shape_vec((3, 3), r.to_vec())
                .expect("3x3")
                .into_pyarray(py),
        )?;
        let t = e.cam_from_world.translation.vector;
        d.set_item("t", vec![t.x, t.y, t.z].into_pyarray(py))?;
        Ok(d)
    }

    /// The textured mesh (`mesh/model.ply` and its texture): a dict with `vertices` (V×3 float32),
    /// `faces` (F×3 uint32, counter-clockwise seen from outside), `uvs` (V×2 float32, v = 0 at the
    /// top of the texture; empty when untextured), `colors` (V×3 uint8 or empty) and `texture`
    /// (H×W×3 uint8, or None).
    fn mesh<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let dir = self.root.join(stage::MESH);
        let ply = dir.join(files::MODEL_PLY);
        if !ply.exists() {
            return Err(HandheldError::new_err(format!(
                "{}: no mesh (run the mesh stage; with `mesh.mode` per-view there is no fused mesh)",
                ply.display()
            )));
        }
        let mesh = py
            .detach(|| handheld_io::ply::read_mesh(&ply))
            .map_err(io_err)?;
        let d = PyDict::new(py);
        d.set_item("vertices", rows(py, mesh.vertices.positions))?;
        d.set_item("faces", rows(py, mesh.faces))?;
        d.set_item("uvs", rows(py, mesh.uvs))?;
        d.set_item("colors", rows(py, mesh.vertices.colors))?;
        let png = texture_path(&dir);
        match png {
            Some(p) => {
                let img = py
                    .detach(|| image::open(&p))
                    .map_err(|err| {
                        HandheldError::new_err(format!(
                            "{}: cannot read the texture ({err}); rerun the mesh stage",
                            p.display()
                        ))
                    })?
                    .into_rgb8();
                let (w, h) = (img.width() as usize, img.height() as usize);
                let a = Array3::from_shape_vec((h, w, 3), img.into_raw()).expect("h×w×3");
                d.set_item("texture", a.into_pyarray(py))?;
            }
            None => d.set_item("texture", py.None())?,
        }
        Ok(d)
    }
}

/// The OBJ's texture beside `model.obj` (`model.png`), if written.
fn texture_path(dir: &Path) -> Option<PathBuf> {
    let p = dir.join(files::MODEL_OBJ).with_extension("png");
    p.exists().then_some(p)
}

/// An image's keypoint positions and the ids of the points they observe.
type Keypoints<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<i64>>);

/// A sparse model as numpy arrays, one row per image and per point, in increasing id order.
#[pyclass(frozen, get_all, module = "handheld")]
pub struct SparseModel {
    /// `(N,)` uint32: COLMAP image ids.
    image_ids: Py<PyArray1<u32>>,
    /// N names, relative to the image folder.
    image_names: Py<PyList>,
    /// `(N,)` uint32.
    camera_ids: Py<PyArray1<u32>>,
    /// `(N, 3, 3)`: the rotation of `cam_from_world`.
    rotations: Py<PyArray3<f64>>,
    /// `(N, 3)`: the translation of `cam_from_world`.
    translations: Py<PyArray2<f64>>,
    /// `(N, 4)`: the rotation as a quaternion `(x, y, z, w)`, as pycolmap's `Rotation3d.quat`.
    quaternions: Py<PyArray2<f64>>,
    /// `(N, 3)`: the camera centres in the world frame (`-Rᵀ t`).
    centers: Py<PyArray2<f64>>,
    /// `(N, 3, 3)`: each image's calibration matrix.
    intrinsics: Py<PyArray3<f64>>,
    /// `{camera_id: {camera_id, model, width, height, params, K}}`.
    cameras: Py<PyDict>,
    /// `(M,)` uint64: COLMAP point ids.
    point_ids: Py<PyArray1<u64>>,
    /// `(M, 3)`.
    xyz: Py<PyArray2<f64>>,
    /// `(M, 3)` uint8.
    rgb: Py<PyArray2<u8>>,
    /// `(M,)`: mean reprojection error in pixels.
    errors: Py<PyArray1<f64>>,
    /// `(M,)` uint32: the number of images that see each point.
    track_lengths: Py<PyArray1<u32>>,
    keypoints: Vec<(Vec<[f64; 2]>, Vec<i64>)>,
}

impl SparseModel {
    fn from_colmap(py: Python<'_>, m: &ColmapModel) -> PyResult<Self> {
        let n = m.images.len();
        let mut rot = Vec::with_capacity(9 * n);
        let (mut trans, mut quat, mut cen, mut kmat) = (vec![], vec![], vec![], vec![]);
        let mut keypoints = Vec::with_capacity(n);
        for im in m.images.values() {
            let r = rotation(im.qvec);
            rot.extend_from_slice(&r);
            trans.push(im.tvec);
            let [w, x, y, z] = im.qvec;
            quat.push([x, y, z, w]);
            let t = im.tvec;
            cen.push(std::array::from_fn::<f64, 3, _>(|j| {
                -(r[j] * t[0] + r[3 + j] * t[1] + r[6 + j] * t[2])
            }));
            let k = m
                .cameras
                .get(&im.camera_id)
                .map(calibration)
                .unwrap_or_else(|| Array2::from_elem((3, 3), f64::NAN));
            kmat.extend(k.iter().copied());
            keypoints.push((
                im.points2d.iter().map(|p| [p.x, p.y]).collect(),
                im.points2d
                    .iter()
                    .map(|p| p.point3d_id.map_or(-1, |id| id as i64))
                    .collect(),
            ));
        }
        let cameras = PyDict::new(py);
        for c in m.cameras.values() {
            cameras.set_item(c.id, camera_dict(py, c)?)?;
        }
        let points = m.points3d.values();
        Ok(Self {
            image_ids: m
                .images
                .keys()
                .copied()
                .collect::<Vec<_>>()
                .into_pyarray(py)
                .unbind(),
            image_names: PyList::new(py, m.images.values().map(|i| i.name.as_str()))?.unbind(),
            camera_ids: m
                .images
                .values()
                .map(|i| i.camera_id)
                .collect::<Vec<_>>()
                .into_pyarray(py)
                .unbind(),
            rotations: Array3::from_shape_vec((n, 3, 3), rot)
                .expect("n×3×3")
                .into_pyarray(py)
                .unbind(),
            translations: rows(py, trans).unbind(),
            quaternions: rows(py, quat).unbind(),
            centers: rows(py, cen).unbind(),
            intrinsics: Array3::from_shape_vec((n, 3, 3), kmat)
                .expect("n×3×3")
                .into_pyarray(py)
                .unbind(),
            cameras: cameras.unbind(),
            point_ids: points
                .clone()
                .map(|p| p.id)
                .collect::<Vec<_>>()
                .into_pyarray(py)
                .unbind(),
            xyz: rows(py, points.clone().map(|p| p.xyz).collect()).unbind(),
            rgb: rows(py, points.clone().map(|p| p.rgb).collect()).unbind(),
            errors: points
                .clone()
                .map(|p| p.error)
                .collect::<Vec<_>>()
                .into_pyarray(py)
                .unbind(),
            track_lengths: Array1::from_iter(points.map(|p| p.track.len() as u32))
                .into_pyarray(py)
                .unbind(),
            keypoints,
        })
    }
}

#[pymethods]
impl SparseModel {
    fn __len__(&self) -> usize {
        self.keypoints.len()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "handheld.SparseModel({} images, {} cameras, {} points)",
            self.keypoints.len(),
            self.cameras.bind(py).len(),
            self.xyz.bind(py).len().unwrap_or(0)
        )
    }

    /// The keypoints of the image at row `index` (in `image_ids` order): `(K, 2)` positions in
    /// COLMAP's pixel convention and `(K,)` int64 ids of the 3D point each one observes (-1: none).
    fn keypoints<'py>(&self, py: Python<'py>, index: usize) -> PyResult<Keypoints<'py>> {
        let Some((xy, ids)) = self.keypoints.get(index) else {
            return Err(pyo3::exceptions::PyIndexError::new_err(format!(
                "image row {index}: the model has {} images",
                self.keypoints.len()
            )));
        };
        Ok((rows(py, xy.clone()), ids.clone().into_pyarray(py)))
    }
}
