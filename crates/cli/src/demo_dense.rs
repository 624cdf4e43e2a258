//! The demo's depth accuracy: each dense depth map against the exact rendered depth, after
//! bringing the model's units to metres with the similarity that aligns the camera centres.

use std::path::Path;

use anyhow::{Context, Result};
use handheld_core::{MetricReconstruction, Sim3, View};
use serde_json::json;

/// A demo's ground truth and estimated model, with the similarity (model → ground truth) that
/// aligns the registered camera centres.
pub struct Aligned {
    pub gt: MetricReconstruction,
    pub est: MetricReconstruction,
    pub sim: Sim3,
    video: bool,
}

impl Aligned {
    pub fn load(out: &Path, workspace: &Path, video: bool) -> Result<Self> {
        let gt =
            handheld_io::colmap::read_reconstruction(&out.join("ground_truth").join("sparse"))?;
        let est = handheld_io::colmap::read_reconstruction(&workspace.join("sparse"))?;
        let mut a = Self {
            gt,
            est,
            sim: Sim3::identity(),
            video,
        };
        let pairs = a.pairs();
        if pairs.len() < 3 {
            anyhow::bail!("only {} views registered", pairs.len());
        }
        let src: Vec<_> = pairs.iter().map(|p| p.0.center()).collect();
        let dst: Vec<_> = pairs.iter().map(|p| p.1.center()).collect();
        a.sim = Sim3::align(&src, &dst).context("aligning the camera centres")?;
        Ok(a)
    }

    /// (estimated view, ground-truth view) for every registered view.
    pub fn pairs(&self) -> Vec<(&View, &View)> {
        let by_name = super::demo::gt_by_name(&self.gt, self.video);
        self.est
            .views
            .values()
            .filter_map(|v| by_name.get(v.name.as_str()).map(|g| (v, *g)))
            .collect()
    }
}

/// Median relative depth error and fill (over pixels where the ground truth has a surface) of
/// every dense depth map in `workspace/dense/depth/`.
pub fn dense_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<serde_json::Value> {
    let aligned = Aligned::load(out, workspace, video)?;
    let (pairs, sim) = (aligned.pairs(), aligned.sim);
    let ddir = workspace.join("dense").join("depth");
    let (mut errors, mut gt_pixels, mut maps) = (Vec::new(), 0usize, 0usize);
    for (e, g) in &pairs {
        let path = ddir.join(format!("{}.pfm", e.name));
        if !path.exists() {
            continue;
        }
        let depth = handheld_io::pfm::read_pfm(&path)?;
        let stem = Path::new(&g.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let truth = handheld_io::pfm::read_pfm(
            &out.join("ground_truth")
                .join("depth")
                .join(format!("{stem}.pfm")),
        )?;
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
        anyhow::bail!(
            "no dense depth map at the rendered resolution in {}",
            ddir.display()
        );
    }
    errors.sort_by(f64::total_cmp);
    let q = |p: f64| {
        errors
            .get(((errors.len() as f64 - 1.0) * p) as usize)
            .copied()
    };
    Ok(json!({
        "depth_maps": maps,
        "fill": errors.len() as f64 / gt_pixels.max(1) as f64,
        "relative_error_median": q(0.5),
        "relative_error_p90": q(0.9),
        "within_1pct": errors.iter().filter(|e| **e <= 0.01).count() as f64 / gt_pixels.max(1) as f64,
    }))
}

/// Middlebury multi-view accuracy (90%) and completeness (within 1% of the scene size) of the
/// fused mesh against the exact scene mesh, over the scene surface the rendered views saw.
pub fn mesh_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<serde_json::Value> {
    use handheld_mesh::{eval::visible_surface_samples, evaluate, EvalOptions, PosedView};
    let aligned = Aligned::load(out, workspace, video)?;
    let (gt, sim) = (&aligned.gt, aligned.sim);
    let mut mesh = handheld_io::ply::read_mesh(&workspace.join("mesh").join("model.ply"))?;
    for p in mesh.vertices.positions.iter_mut() {
        let q = sim.transform_point(&nalgebra::Point3::new(
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
        ));
        *p = [q.x as f32, q.y as f32, q.z as f32];
    }
    let truth = handheld_io::ply::read_mesh(&out.join("ground_truth").join("mesh.ply"))?;
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
        let stem = Path::new(&g.name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        depths.push((
            g,
            handheld_io::pfm::read_pfm(
                &out.join("ground_truth")
                    .join("depth")
                    .join(format!("{stem}.pfm")),
            )?,
        ));
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
    Ok(json!({
        "faces": mesh.faces.len(),
        "scene_size_m": size,
        "accuracy_90_m": s.accuracy,
        "accuracy_90_pct_of_scene": 100.0 * s.accuracy / size,
        "completeness_within_1pct": s.completeness,
    }))
}
