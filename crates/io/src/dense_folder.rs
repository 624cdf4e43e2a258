//! The dense stage's folder, one reader and one writer for it:
//! - `cameras.json`: the views in sequence order, an array of `{image, camera, cam_from_world}`
//!   (the camera each map belongs to: downscaled views have a scaled camera);
//! - `depth/<image>.pfm`: camera-frame `z`, model units, `NaN` where nothing was kept;
//! - `variance/<image>.pfm`: the depth's variance (model units²);
//! - `confidence/<image>.pfm`: the fusion weight (`1 / (1 + σ/(0.005·z))`);
//! - `visibility/<image>.pfm`: the number of views linked (reference included).
//!
//! Maps are one-channel PFM files at the camera's size ([`crate::pfm`]); every file is written
//! atomically. Images are not stored: [`read_views`] loads them from the input folder.

use std::path::{Path, PathBuf};

use handheld_core::{Camera, FloatMap, PosedCamera, PosedView, Rigid3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::atomic::write_bytes_atomic;
use crate::error::{IoError, Result};
use crate::images::{load_image, ImageIngestOptions};
use crate::pfm::{read_pfm, write_pfm};

/// The file of the view list inside a dense folder.
pub const CAMERAS_FILE: &str = "cameras.json";

/// One entry of `cameras.json`: a view's image name, camera and pose.
///
/// A type of its own (rather than a name and a [`PosedCamera`]) because it *is* the file format:
/// its three flat keys `image`, `camera`, `cam_from_world` are what `cameras.json` has always
/// held, and renaming or nesting a field here would break every workspace already written.
/// Convert with [`CameraEntry::from`] (a [`PosedView`]) and [`CameraEntry::to_posed`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraEntry {
    /// The image's name (the maps are `<kind>/<image>.pfm`).
    pub image: String,
    /// The camera the maps belong to.
    pub camera: Camera,
    /// World → camera.
    pub cam_from_world: Rigid3,
}

impl CameraEntry {
    /// The entry's camera in its pose.
    pub fn to_posed(&self) -> PosedCamera {
        PosedCamera::new(self.camera.clone(), self.cam_from_world)
    }
}

impl From<&PosedView> for CameraEntry {
    fn from(v: &PosedView) -> Self {
        Self {
            image: v.name.clone(),
            camera: v.posed.camera.clone(),
            cam_from_world: v.posed.cam_from_world,
        }
    }
}

/// The per-view maps of a dense folder, each in its own sub-folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapKind {
    Depth,
    Variance,
    Confidence,
    Visibility,
}

impl MapKind {
    /// Every kind, in the order the dense stage writes them.
    pub const ALL: [MapKind; 4] = [
        MapKind::Depth,
        MapKind::Variance,
        MapKind::Confidence,
        MapKind::Visibility,
    ];

    /// The sub-folder name (`depth`, `variance`, `confidence`, `visibility`).
    pub fn dir_name(self) -> &'static str {
        match self {
            MapKind::Depth => "depth",
            MapKind::Variance => "variance",
            MapKind::Confidence => "confidence",
            MapKind::Visibility => "visibility",
        }
    }

    /// The map of this kind in `view`, if any.
    pub fn of(self, view: &PosedView) -> Option<&FloatMap> {
        match self {
            MapKind::Depth => view.depth.as_ref(),
            MapKind::Variance => view.variance.as_ref(),
            MapKind::Confidence => view.confidence.as_ref(),
            MapKind::Visibility => view.visibility.as_ref(),
        }
    }

    fn slot(self, view: &mut PosedView) -> &mut Option<FloatMap> {
        match self {
            MapKind::Depth => &mut view.depth,
            MapKind::Variance => &mut view.variance,
            MapKind::Confidence => &mut view.confidence,
            MapKind::Visibility => &mut view.visibility,
        }
    }
}

/// `<kind>/<image>.pfm`, relative to the dense folder.
pub fn map_file(kind: MapKind, image: &str) -> String {
    format!("{}/{image}.pfm", kind.dir_name())
}

/// Writes the maps `view` holds to `dir/<kind>/<name>.pfm` (creating the sub-folders), in the
/// order of [`MapKind::ALL`]; returns the files written, relative to `dir`.
pub fn write_view(dir: &Path, view: &PosedView) -> Result<Vec<String>> {
    let mut written = Vec::new();
    for kind in MapKind::ALL {
        if let Some(map) = kind.of(view) {
            let file = map_file(kind, &view.name);
            write_pfm(&dir.join(&file), map)?;
            written.push(file);
        }
    }
    Ok(written)
}

/// Writes `dir/cameras.json` (atomically): the views' names, cameras and poses, in order.
pub fn write_cameras<'a>(dir: &Path, views: impl IntoIterator<Item = &'a PosedView>) -> Result<()> {
    let path = dir.join(CAMERAS_FILE);
    let entries: Vec<CameraEntry> = views.into_iter().map(CameraEntry::from).collect();
    // Through a JSON value, so the key order is serde_json's map order (as the file always had).
    let bytes = serde_json::to_value(&entries)
        .and_then(|v| serde_json::to_vec_pretty(&v))
        .map_err(|e| IoError::format(&path, format!("cannot encode the cameras: {e}")))?;
    write_bytes_atomic(&path, &bytes)
}

/// Reads `dir/cameras.json`.
pub fn read_cameras(dir: &Path) -> Result<Vec<CameraEntry>> {
    let path = dir.join(CAMERAS_FILE);
    let bytes = std::fs::read(&path).map_err(|e| IoError::Input {
        path: path.clone(),
        reason: format!("cannot read ({e}); run the dense stage first"),
    })?;
    serde_json::from_slice(&bytes).map_err(|e| IoError::Input {
        path: path.clone(),
        reason: format!("corrupt ({e}); rerun the dense stage"),
    })
}

/// Reads the views of the dense folder `dir`, in the order of `cameras.json`: each view's camera
/// and pose, its image (found by `image_path(name)`, loaded with [`load_image`] and resized to the
/// camera's size when the dense stage downscaled it), its depth map (required), and the other
/// `maps` when their files exist (`MapKind::Depth` in `maps` changes nothing).
pub fn read_views(
    dir: &Path,
    image_path: impl Fn(&str) -> Option<PathBuf> + Sync,
    maps: &[MapKind],
) -> Result<Vec<PosedView>> {
    let entries = read_cameras(dir)?;
    entries
        .into_par_iter()
        .map(|e| read_view(dir, e, &image_path, maps))
        .collect()
}

fn read_view(
    dir: &Path,
    e: CameraEntry,
    image_path: &(impl Fn(&str) -> Option<PathBuf> + Sync),
    maps: &[MapKind],
) -> Result<PosedView> {
    let (cw, ch) = (e.camera.width as usize, e.camera.height as usize);
    let read_map = |kind: MapKind| -> Result<FloatMap> {
        let path = dir.join(map_file(kind, &e.image));
        let map = read_pfm(&path).map_err(|err| IoError::Input {
            path: path.clone(),
            reason: format!(
                "cannot read the {} map ({err}); rerun the dense stage",
                kind.dir_name()
            ),
        })?;
        if (map.width, map.height) != (cw, ch) {
            return Err(IoError::Input {
                path,
                reason: format!(
                    "{} map is {}x{} but its camera is {cw}x{ch}; rerun the dense stage",
                    kind.dir_name(),
                    map.width,
                    map.height
                ),
            });
        }
        Ok(map)
    };
    let depth = read_map(MapKind::Depth)?;
    let mut others = Vec::new();
    for &kind in maps.iter().filter(|k| **k != MapKind::Depth) {
        if dir.join(map_file(kind, &e.image)).exists() {
            others.push((kind, read_map(kind)?));
        }
    }
    let path = image_path(&e.image).ok_or_else(|| IoError::Input {
        path: PathBuf::from(&e.image),
        reason: "no such image among the inputs; check the image folder".into(),
    })?;
    let opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let img = load_image(&path, &opts)?.image.to_rgb8();
    let image = if (img.width(), img.height()) == (e.camera.width, e.camera.height) {
        img
    } else {
        image::imageops::resize(
            &img,
            e.camera.width,
            e.camera.height,
            image::imageops::FilterType::Triangle,
        )
    };
    let mut view = PosedView::new(e.image, e.camera, e.cam_from_world, image);
    view.depth = Some(depth);
    for (kind, map) in others {
        *kind.slot(&mut view) = Some(map);
    }
    Ok(view)
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::{CameraId, Intrinsics};
    use nalgebra::Vector3;

    fn view(name: &str, w: u32, h: u32) -> PosedView {
        let camera = Camera {
            id: CameraId(1),
            width: w,
            height: h,
            intrinsics: Intrinsics::pinhole(20.0, 3.5, 2.5),
        };
        let pose = Rigid3::new(Vector3::new(0.5, -1.0, 2.0), Vector3::new(0.1, 0.2, 0.3));
        let mut v = PosedView::new(name, camera, pose, image::RgbImage::new(w, h));
        v.depth = Some(FloatMap::filled(w as usize, h as usize, 1, 2.5));
        v.confidence = Some(FloatMap::filled(w as usize, h as usize, 1, 0.5));
        v
    }

    #[test]
    fn views_round_trip_with_images_resized_to_their_camera() {
        let dir = tempfile::tempdir().unwrap();
        let dense = dir.path().join("dense");
        let views = vec![view("a.png", 8, 6), view("b.png", 8, 6)];
        let written = write_view(&dense, &views[0]).unwrap();
        assert_eq!(written, ["depth/a.png.pfm", "confidence/a.png.pfm"]);
        write_view(&dense, &views[1]).unwrap();
        write_cameras(&dense, &views).unwrap();
        assert_eq!(read_cameras(&dense).unwrap().len(), 2);
        // The images on disk are twice the cameras' size (a downscaled dense stage).
        let images = dir.path().join("images");
        std::fs::create_dir_all(&images).unwrap();
        for n in ["a.png", "b.png"] {
            image::RgbImage::from_pixel(16, 12, image::Rgb([10, 20, 30]))
                .save(images.join(n))
                .unwrap();
        }
        let back = read_views(&dense, |n| Some(images.join(n)), &MapKind::ALL).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[0].name, "a.png");
        assert_eq!(back[0].posed.camera, views[0].posed.camera);
        assert_eq!(back[0].depth, views[0].depth);
        assert_eq!(back[0].confidence, views[0].confidence);
        assert_eq!(back[0].variance, None);
        assert_eq!(back[0].image.dimensions(), (8, 6));
        assert_eq!(back[0].rgb(3, 3), [10, 20, 30]);
        assert!(back[1].validate().is_ok());
        let depth_only = read_views(&dense, |n| Some(images.join(n)), &[]).unwrap();
        assert_eq!(depth_only[0].confidence, None);
    }

    #[test]
    fn errors_name_the_file_and_what_to_do() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_cameras(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("cameras.json") && e.contains("run the dense stage"),
            "{e}"
        );
        std::fs::write(dir.path().join(CAMERAS_FILE), b"[{").unwrap();
        let e = read_cameras(dir.path()).unwrap_err().to_string();
        assert!(e.contains("corrupt"), "{e}");
        let v = view("a.png", 8, 6);
        write_cameras(dir.path(), std::slice::from_ref(&v)).unwrap();
        let e = read_views(dir.path(), |_| None, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("depth/a.png.pfm"), "{e}");
        let mut small = v.clone();
        small.depth = Some(FloatMap::filled(4, 3, 1, 1.0));
        write_view(dir.path(), &small).unwrap();
        let e = read_views(dir.path(), |_| None, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("4x3 but its camera is 8x6"), "{e}");
        write_view(dir.path(), &v).unwrap();
        let e = read_views(dir.path(), |_| None, &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("no such image among the inputs"), "{e}");
    }
}
