//! The augmented demo (`handheld demo --video --augment`), scored against the ground truth: the
//! placed object's vertices are projected with our cameras and, after the similarity that aligns
//! our model to the truth, with the exact cameras; the image distances over all frames and
//! vertices, and the image jitter of the anchored point against the exact cameras' own.

use std::path::Path;

use handheld_pipeline::augment::ObjectSource;
use handheld_pipeline::augment::{PlacementFile, PLACEMENT_JSON};
use handheld_pipeline::files;
use handheld_render::augment::{anchor_of, placed_vertices};
use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

use super::accuracy::{median_nan, Aligned};
use crate::error::{EvalError, Result};

/// Image distances between the object drawn with our cameras and with the exact ones.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ProjectionError {
    pub median_px: f64,
    pub max_px: f64,
    /// RMS second difference of the anchor's track with our cameras, and with the exact ones.
    pub jitter_px: f64,
    pub jitter_gt_px: f64,
    /// `jitter_px − jitter_gt_px` (the measure).
    pub jitter_above_gt_px: f64,
    /// RMS second difference of the difference of the two tracks (the jitter our cameras add).
    pub added_jitter_px: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AugmentAccuracy {
    pub frames: usize,
    pub vertices: usize,
    /// Drawn as the stage draws it (radial distortion applied).
    pub with_distortion: ProjectionError,
    /// Drawn ignoring the radial distortion (k1 = k2 = 0), against the same exact projections.
    pub without_distortion: ProjectionError,
}

pub fn augment_accuracy(out: &Path, workspace: &Path, video: bool) -> Result<AugmentAccuracy> {
    let aligned = Aligned::load(out, workspace, video)?;
    let dir = workspace.join(files::stage::AUGMENT);
    let path = dir.join(PLACEMENT_JSON);
    let bytes = std::fs::read(&path).map_err(|e| handheld_io::IoError::io(&path, e))?;
    let placement: PlacementFile = serde_json::from_slice(&bytes)
        .map_err(|e| handheld_io::IoError::format(&path, e.to_string()))?;
    let (object, _) = ObjectSource::Box.load()?;
    let verts = placed_vertices(&object, &placement.placement);
    let anchor = anchor_of(&object, &placement.placement);
    let sim = aligned.sim;
    let mut pairs = aligned.pairs();
    pairs.sort_by(|a, b| a.0.name.cmp(&b.0.name));
    let score = |distort: bool| -> Result<ProjectionError> {
        let mut errs = Vec::new();
        let mut ours = Vec::new();
        let mut theirs = Vec::new();
        for (e, g) in &pairs {
            let (Some(ec), Some(gc)) = (
                aligned.est.cameras.get(&e.camera_id),
                aligned.gt.cameras.get(&g.camera_id),
            ) else {
                continue;
            };
            let mut ec = ec.clone();
            if !distort {
                ec.intrinsics.k1 = 0.0;
                ec.intrinsics.k2 = 0.0;
            }
            for v in &verts {
                if let (Some(a), Some(b)) = (
                    ec.project(&e.cam_from_world, v),
                    gc.project(&g.cam_from_world, &sim.transform_point(v)),
                ) {
                    errs.push((a - b).norm());
                }
            }
            ours.push(ec.project(&e.cam_from_world, &anchor));
            theirs.push(gc.project(&g.cam_from_world, &sim.transform_point(&anchor)));
        }
        if errs.is_empty() {
            return Err(EvalError::Data("the object projects into no frame".into()));
        }
        let max = errs.iter().fold(0.0f64, |a, b| a.max(*b));
        let diff: Vec<Option<Vector2<f64>>> = ours
            .iter()
            .zip(&theirs)
            .map(|(a, b)| Some((*a)? - (*b)?))
            .collect();
        let j = handheld_render::augment::jitter(&ours);
        let jg = handheld_render::augment::jitter(&theirs);
        Ok(ProjectionError {
            median_px: median_nan(&mut errs),
            max_px: max,
            jitter_px: j,
            jitter_gt_px: jg,
            jitter_above_gt_px: j - jg,
            added_jitter_px: handheld_render::augment::jitter(&diff),
        })
    };
    Ok(AugmentAccuracy {
        frames: pairs.len(),
        vertices: verts.len(),
        with_distortion: score(true)?,
        without_distortion: score(false)?,
    })
}
