//! A workspace (or any dense folder and textured model) loaded as a [`RenderScene`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::PosedView;
use handheld_io::dense_folder::{read_views, MapKind};
use image::RgbImage;
use nalgebra::Point3;

use crate::error::{PipelineError, Result};
use crate::files::{stage, MODEL_GLB};
use crate::manifest::Workspace;
use handheld_render::scene::{RenderScene, SceneError};

/// Loads the workspace's dense views (or, without a dense stage, the sparse model's views and
/// images at most `max_size` pixels wide, with the fixed plane only) and its textured mesh,
/// leaving out `exclude`.
pub fn load_scene(ws: &Workspace, exclude: &[String], max_size: u32) -> Result<RenderScene> {
    let rec = ws.read_sparse_model()?;
    let paths = ws.image_paths()?;
    scene_from_folders(
        &rec,
        &paths,
        &ws.root.join(stage::DENSE),
        Some(&ws.path(stage::MESH, MODEL_GLB)),
        exclude,
        max_size,
    )
}

/// [`load_scene`] on a sparse model, its images, a dense folder and a textured model (each
/// used when it exists).
pub fn scene_from_folders(
    rec: &handheld_core::MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    dense: &Path,
    mesh_glb: Option<&Path>,
    exclude: &[String],
    max_size: u32,
) -> Result<RenderScene> {
    let points: Vec<Point3<f64>> = rec.points.values().map(|p| p.xyz).collect();
    let mut warnings = Vec::new();
    let views: Vec<PosedView> = if dense.join(handheld_io::dense_folder::CAMERAS_FILE).exists() {
        read_views(dense, |n| paths.get(n).cloned(), &[MapKind::Depth])?
    } else {
        warnings.push(
            "no dense depth maps in the workspace (run `handheld reconstruct` through the dense stage): \
             every method falls back to the fixed plane"
                .into(),
        );
        load_sparse_views(rec, paths, max_size)?
    };
    let views: Vec<PosedView> = views
        .into_iter()
        .filter(|v| !exclude.contains(&v.name))
        .collect();
    let mesh = match mesh_glb {
        Some(glb) if glb.exists() => Some(handheld_io::glb::read_glb(glb)?),
        _ => None,
    };
    RenderScene::new(&views, points, mesh, warnings)
        .map_err(|e| PipelineError::workspace(dense, e.to_string()))
}

/// A scene error as the pipeline's: an option names its flag.
pub(crate) fn scene_error(e: SceneError) -> PipelineError {
    e.into()
}

/// The sparse model's views with their images (no depth), downscaled to `max_size`.
fn load_sparse_views(
    rec: &handheld_core::MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    max_size: u32,
) -> Result<Vec<PosedView>> {
    let opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    rec.views
        .values()
        .map(|v| {
            let path = paths.get(&v.name).ok_or_else(|| PipelineError::Input {
                path: v.name.clone().into(),
                reason: "no such image among the inputs".into(),
            })?;
            let cam = rec.cameras.get(&v.camera_id).ok_or_else(|| {
                PipelineError::workspace(&v.name, "camera missing from the sparse model")
            })?;
            let img = handheld_io::images::load_image(path, &opts)?
                .image
                .to_rgb8();
            let longer = img.width().max(img.height());
            let (img, cam) = if max_size > 0 && longer > max_size {
                let s = f64::from(max_size) / f64::from(longer);
                let (w, h) = (
                    (f64::from(img.width()) * s).round() as u32,
                    (f64::from(img.height()) * s).round() as u32,
                );
                let small =
                    image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
                let sx = f64::from(w) / f64::from(img.width());
                let sy = f64::from(h) / f64::from(img.height());
                (small, cam.scaled(sx, sy))
            } else {
                (img, cam.clone())
            };
            Ok(PosedView::new(v.name.clone(), cam, v.cam_from_world, img))
        })
        .collect()
}

/// Writes a rendering as PNG, atomically.
pub fn write_png(path: &Path, image: &RgbImage) -> Result<()> {
    let bytes = handheld_io::obj::encode_png(path, image)?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}
