//! The demo's depth and mesh accuracy: each dense depth map against the exact rendered depth, and
//! the fused mesh against the exact scene mesh, after bringing the model's units to metres with the
//! similarity that aligns the camera centres.

use std::path::Path;

use handheld_mesh::{eval::visible_surface_samples, evaluate, EvalOptions, PosedView};
use handheld_pipeline::files;
use serde::{Deserialize, Serialize};

use super::accuracy::Aligned;
use super::sequence::{gt_depth_path, GROUND_TRUTH_DIR};
use crate::error::{EvalError, Result};

/// The dense depth maps against the exact rendered depth.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DenseAccuracy {
    /// Depth maps at the rendered resolution that were scored.
    pub depth_maps: usize,
    /// Fraction of the pixels with a true surface that have a depth.
    pub fill: f64,
    /// Relative depth error |z − z_true| / z_true: median and 90th percentile.
    pub relative_error_median: Option<f64>,
    pub relative_error_p90: Option<f64>,
    /// Fraction of the pixels with a true surface whose depth is within 1 %.
    pub within_1pct: f64,
}

/// Median relative depth error and fill (over pixels where the ground truth has a surface) of
/// every dense depth map in `workspace/dense/depth/`.
pub fn dense_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<DenseAccuracy> {
    let aligned = Aligned::load(out, workspace, video)?;
    let (pairs, sim) = (aligned.pairs(), aligned.sim);
    let ddir = workspace.join(files::stage::DENSE).join("depth");
    let (mut errors, mut gt_pixels, mut maps) = (Vec::new(), 0usize, 0usize);
    for (e, g) in &pairs {
        let path = ddir.join(format!("{}.pfm", e.name));
        if !path.exists() {
            continue;
        }
        let depth = handheld_io::pfm::read_pfm(&path)?;
        let truth = handheld_io::pfm::read_pfm(&gt_depth_path(out, &g.name))?;
        if (depth.width, depth.height) != (truth.width, truth.height) {
            continue;
        }
        maps += 1;
        for (z, t) in depth.data.iter().zip(&truth.data) {
            if *t <= 0.0 {
                continue;
            }
            gt_pixels += 1;
            if z.is_finite() {
                errors.push(((sim.scale * f64::from(*z) - f64::from(*t)) / f64::from(*t)).abs());
            }
        }
    }
    if maps == 0 {
        return Err(EvalError::Data(format!(
            "no dense depth map at the rendered resolution in {}",
            ddir.display()
        )));
    }
    errors.sort_by(f64::total_cmp);
    let q = |p: f64| {
        errors
            .get(((errors.len() as f64 - 1.0) * p) as usize)
            .copied()
    };
    let pixels = gt_pixels.max(1) as f64;
    Ok(DenseAccuracy {
        depth_maps: maps,
        fill: errors.len() as f64 / pixels,
        relative_error_median: q(0.5),
        relative_error_p90: q(0.9),
        within_1pct: errors.iter().filter(|e| **e <= 0.01).count() as f64 / pixels,
    })
}

/// The fused mesh against the exact scene mesh (Middlebury multi-view measures).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MeshAccuracy {
    /// Faces of the fused mesh.
    pub faces: usize,
    /// Diagonal of the true mesh's bounding box (metres).
    pub scene_size_m: f64,
    /// Distance within which 90 % of the mesh lies from the true surface (metres, % of the scene).
    pub accuracy_90_m: f64,
    pub accuracy_90_pct_of_scene: f64,
    /// Fraction of the seen true surface within 1 % of the scene size of the mesh.
    pub completeness_within_1pct: f64,
}

/// Middlebury multi-view accuracy (90%) and completeness (within 1% of the scene size) of the
/// fused mesh against the exact scene mesh, over the scene surface the rendered views saw.
pub fn mesh_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<MeshAccuracy> {
    let aligned = Aligned::load(out, workspace, video)?;
    let (gt, sim) = (&aligned.gt, aligned.sim);
    let mut mesh =
        handheld_io::ply::read_mesh(&workspace.join(files::stage::MESH).join(files::MODEL_PLY))?;
    for p in mesh.vertices.positions.iter_mut() {
        let q = sim.transform_point(&nalgebra::Point3::new(
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
        ));
        *p = [q.x as f32, q.y as f32, q.z as f32];
    }
    let truth = handheld_io::ply::read_mesh(&out.join(GROUND_TRUTH_DIR).join("mesh.ply"))?;
    let (mut lo, mut hi) = ([f64::MAX; 3], [f64::MIN; 3]);
    for p in &truth.vertices.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(f64::from(p[k]));
            hi[k] = hi[k].max(f64::from(p[k]));
        }
    }
    let size = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
    let mut depths = Vec::new();
    for g in gt.views.values() {
        depths.push((g, handheld_io::pfm::read_pfm(&gt_depth_path(out, &g.name))?));
    }
    // Only the depth maps are read: the views carry no image.
    let views: Vec<PosedView> = depths
        .into_iter()
        .filter_map(|(g, d)| {
            let camera = gt.cameras.get(&g.camera_id)?.clone();
            let mut v = PosedView::new(&g.name, camera, g.cam_from_world, Default::default());
            v.depth = Some(d);
            Some(v)
        })
        .collect();
    let samples = visible_surface_samples(&views, 4)?;
    let opts = EvalOptions {
        accuracy_fraction: 0.9,
        completeness_threshold: 0.01 * size,
        sample_spacing: 0.002 * size,
    };
    let s = evaluate(&mesh, &truth, &samples, &opts)?;
    Ok(MeshAccuracy {
        faces: mesh.faces.len(),
        scene_size_m: size,
        accuracy_90_m: s.accuracy,
        accuracy_90_pct_of_scene: 100.0 * s.accuracy / size,
        completeness_within_1pct: s.completeness,
    })
}
