//! The dense stage (§4): reads the sparse model and the images, calls
//! `handheld_dense::dense_reconstruct` and writes `dense/`:
//! - `depth/<image>.pfm`: z-depth in the camera frame of the sparse model, model units, `NaN`
//!   where nothing was kept (full-resolution maps unless `max_size` or `max_megapixels`
//!   downscaled the view;
//!   `cameras.json` holds the camera each map belongs to);
//! - `variance/<image>.pfm`: the Kalman-fused depth variance (model units²);
//! - `confidence/<image>.pfm`: `1 / (1 + σ/(0.005·z))` (`LinkedDepth::confidence`), 0.5 where the 1σ
//!   error is 0.5% of depth;
//! - `visibility/<image>.pfm`: V, the number of views linked (reference included);
//! - `preview/<image>.depth.png` and `preview/<image>.visibility.png`;
//! - `fused.ply`, the coloured point cloud; `summary.json`.
//!
//! Video workspaces use their key-frames only.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use handheld_core::{ImageId, MetricReconstruction, PosedView, Progress};
use handheld_dense::{
    dense_reconstruct_with, DenseOptions, PairDisparity, SequenceOrder, SparsePoints, StereoMethod,
    StereoOptions,
};
use handheld_io::dense_folder::{write_cameras, write_view, MapKind, CAMERAS_FILE};
use handheld_io::images::{load_image, ImageIngestOptions};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Context, PipelineError, Result};
use crate::files::{stage, write_json, FUSED_PLY, PREVIEW_DIR, SUMMARY_JSON};
use crate::manifest::Workspace;
use crate::policy::image_id;
use crate::preview::write_preview;
use crate::stage::{Produced, Stage, StageContext, SummaryFile};
use crate::warning::{code, Warning};

/// Options of the dense stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct DenseStageOptions {
    /// Images are downscaled so their longer side is at most this (0, the default: no limit).
    pub max_size: u32,
    /// Images larger than this many megapixels are downscaled to it. Default 24: a phone's
    /// 12 MP and a drone's 20 MP are matched at their own size (coarse to fine keeps the search
    /// per pixel small).
    pub max_megapixels: f64,
    /// Memory the views' maps may take, in GB: the mesh stage holds every view's depth,
    /// variance and confidence maps, its image and its incidence cosines (about
    /// [`BYTES_PER_VIEW_PIXEL`] bytes a pixel), so many large views are downscaled until they fit.
    /// 0 (the default): 60 % of the machine's memory.
    pub max_memory_gb: f64,
    pub dense: DenseOptions,
}

/// Bytes a view's pixel costs at the peak of a run: the mesh stage's depth, variance and
/// confidence (`f32`), RGB and incidence (`u16`) are 17, and the measured peak of the whole
/// pipeline on a phone set (23 views of 12.2 MP: 9.1 GB) is 32 a pixel.
pub const BYTES_PER_VIEW_PIXEL: f64 = 32.0;

/// The machine's memory in bytes (`/proc/meminfo`), 8 GB where it cannot be read.
fn machine_memory_bytes() -> f64 {
    std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| {
            let line = t.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kb * 1024.0)
        })
        .unwrap_or(8e9)
}

impl Default for DenseStageOptions {
    fn default() -> Self {
        Self {
            max_size: 0,
            max_megapixels: 24.0,
            max_memory_gb: 0.0,
            dense: DenseOptions::default(),
        }
    }
}

impl DenseStageOptions {
    /// The memory budget of the views' maps, in bytes (`max_memory_gb`, or 60 % of the machine's).
    pub fn memory_budget_bytes(&self) -> f64 {
        if self.max_memory_gb > 0.0 {
            self.max_memory_gb * 1e9
        } else {
            0.6 * machine_memory_bytes()
        }
    }

    /// The longer side a `width`×`height` image of a set of `views` is matched at: its own, or
    /// less under `max_size`, `max_megapixels` and the memory budget shared by the views; 0 when
    /// the image is kept as it is.
    pub fn max_size_for(&self, width: u32, height: u32, views: usize) -> u32 {
        let longer = width.max(height);
        let pixels = f64::from(width) * f64::from(height);
        let by_memory = self.memory_budget_bytes() / (views.max(1) as f64 * BYTES_PER_VIEW_PIXEL);
        let cap = (self.max_megapixels * 1e6).min(by_memory.max(0.25e6));
        let by_area = if pixels > cap {
            (f64::from(longer) * (cap / pixels).sqrt()).floor() as u32
        } else {
            0
        };
        match (self.max_size, by_area) {
            (0, a) => a,
            (m, 0) => m,
            (m, a) => m.min(a),
        }
    }

    /// N, the views linked per reference view: the reference and (N−1)/2 on each side (§4.3).
    pub fn link_views(&self) -> usize {
        2 * self.dense.link.max_links + 1
    }

    /// Sets N (odd, at least 3).
    pub fn set_link_views(&mut self, n: usize) -> Result<()> {
        if n < 3 || n.is_multiple_of(2) {
            return Err(PipelineError::option(
                "--link-views",
                format!("must be odd and at least 3, got {n}"),
            ));
        }
        self.dense.link.max_links = (n - 1) / 2;
        Ok(())
    }

    /// The stereo method of every rectified pair (§4.2), with the pair defaults of the dense stage
    /// (SGM path count, no hole filling) kept.
    pub fn stereo_method(&self) -> StereoMethod {
        self.dense.pair.stereo.method
    }

    pub fn set_stereo_method(&mut self, method: StereoMethod) {
        let base = DenseOptions::default().pair.stereo;
        self.dense.pair.stereo = StereoOptions {
            sgm_paths: base.sgm_paths,
            hole_fill: base.hole_fill,
            ..StereoOptions::for_method(method)
        };
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.max_megapixels.is_finite() && self.max_megapixels >= 0.01) {
            return Err(PipelineError::option(
                "--dense-max-megapixels",
                format!("must be at least 0.01, got {}", self.max_megapixels),
            ));
        }
        if !(self.max_memory_gb.is_finite() && self.max_memory_gb >= 0.0) {
            return Err(PipelineError::option(
                "--dense-max-memory-gb",
                format!("must be 0 (auto) or positive, got {}", self.max_memory_gb),
            ));
        }
        let n = self.link_views();
        let link = &self.dense.link;
        if link.max_links < 1 {
            return Err(PipelineError::option(
                "--link-views",
                format!("must be odd and at least 3, got {n}"),
            ));
        }
        for (option, v) in [
            ("--min-visibility", link.min_visibility),
            ("--preferred-visibility", link.preferred_visibility),
        ] {
            if v < 1 || v > n {
                return Err(PipelineError::option(
                    option,
                    format!("must be between 1 and --link-views ({n}), got {v}"),
                ));
            }
        }
        self.dense
            .validate()
            .map_err(|e| PipelineError::invalid(stage::DENSE, e))
    }
}

/// A pair that could not be rectified or matched.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct FailedPair {
    pub pair: [String; 2],
    pub reason: String,
}

/// One view's depth map.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewFill {
    pub image: String,
    pub width: u32,
    pub height: u32,
    pub fill: f64,
    pub seconds: f64,
}

/// What the dense stage computed (`dense/summary.json` adds `per_view`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct DenseStageSummary {
    pub views: usize,
    pub pairs_matched: usize,
    pub polar_pairs: usize,
    pub pairs_failed: Vec<FailedPair>,
    pub fused_points: usize,
    pub seconds_pairs: f64,
    pub seconds_linking: f64,
    pub seconds_per_view: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_view: Option<Vec<ViewFill>>,
    /// The order the views were densified in ([`handheld_dense::densify_order`]); `None` where
    /// the caller chose the views and their order.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence: Option<SequenceOrder>,
}

/// The dense stage.
pub struct Dense {
    pub options: DenseStageOptions,
}

impl Stage for Dense {
    type Options = DenseStageOptions;
    type Summary = DenseStageSummary;

    const NAME: &'static str = stage::DENSE;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::FEATURES, stage::SPARSE];
    const ABOUT: &'static str =
        "rectification, stereo and multi-view linking (§4); writes depth maps and fused.ply";

    fn options(&self) -> &DenseStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    /// One unit per consecutive pair: its rectification and stereo (most of the stage's time);
    /// the linking and the fused cloud stay with the stage.
    fn units(&self, ctx: &StageContext) -> Result<usize> {
        let rec = ctx.ws.read_sparse_model()?;
        Ok(key_views(ctx.ws, &rec)?.0.len().saturating_sub(1))
    }

    fn run_unit(
        &self,
        ctx: &StageContext,
        dir: &Path,
        k: usize,
    ) -> Result<(Vec<String>, serde_json::Value)> {
        let rec = ctx.ws.read_sparse_model()?;
        let (ids, _) = key_views(ctx.ws, &rec)?;
        let Some(pair) = ids.get(k..k + 2) else {
            return Err(PipelineError::Graph(format!(
                "dense: no unit {k} ({} views, {} pairs)",
                ids.len(),
                ids.len().saturating_sub(1)
            )));
        };
        let views = load_views(&ctx.ws.image_paths()?, &rec, pair, ids.len(), &self.options)?;
        // The range's points as the whole sequence selects them (`SparsePoints::for_pair`), so
        // that a pair matched here is the pair the single-machine run matches.
        let points = SparsePoints::from_tracks(rec.points.values(), &ids).for_pair(k, k + 1);
        let outcome =
            handheld_dense::match_pair(&views[0], &views[1], &points, &self.options.dense.pair)
                .map_err(|e| e.to_string());
        let name = pair_file(k);
        let bytes = postcard::to_stdvec(&outcome).map_err(|e| {
            PipelineError::workspace(dir.join(&name), format!("cannot encode the pair: {e}"))
        })?;
        handheld_io::atomic::write_bytes_atomic(&dir.join(&name), &bytes)?;
        Ok((
            vec![name],
            serde_json::json!({ "matched": outcome.is_ok() }),
        ))
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<DenseStageSummary>> {
        let rec = ctx.ws.read_sparse_model()?;
        let (ids, order) = key_views(ctx.ws, &rec)?;
        let paths = ctx.ws.image_paths()?;
        // Pairs matched apart (work units): read when the sliding window reaches them.
        let matched = |p: usize| -> Option<std::result::Result<PairDisparity, String>> {
            let name = pair_file(p);
            ctx.take_unit(p, std::slice::from_ref(&name), dir).ok()??;
            crate::stage::read_unit_outcome(&dir.join(&name))
        };
        densify_with(
            &rec,
            &paths,
            (&ids, Some(order)),
            &self.options,
            dir,
            ctx.progress,
            matched,
        )
    }
}

/// The file of pair unit `p` (pairs `(p, p + 1)` of the views densified).
fn pair_file(p: usize) -> String {
    format!("pair-{p}.bin")
}

/// The views to densify, in sequence order: every registered view, or the key-frames of a video
/// ([`sequence`]).
fn key_views(ws: &Workspace, rec: &MetricReconstruction) -> Result<(Vec<ImageId>, SequenceOrder)> {
    let ids: Vec<ImageId> = rec.views.keys().copied().collect();
    if let Some(tracks) = ws.read_tracks()? {
        let keys: BTreeSet<ImageId> = tracks.keyframes.iter().map(|k| image_id(k.0)).collect();
        let kept: Vec<ImageId> = ids.iter().copied().filter(|i| keys.contains(i)).collect();
        if kept.len() >= 2 {
            return Ok(sequence(rec, kept));
        }
    }
    Ok(sequence(rec, ids))
}

/// `ids` in the given order where it is a good path through the views' shared points, and
/// otherwise along such a path ([`handheld_dense::densify_order`]: shuffled or renamed photos).
fn sequence(rec: &MetricReconstruction, ids: Vec<ImageId>) -> (Vec<ImageId>, SequenceOrder) {
    let points = SparsePoints::from_tracks(rec.points.values(), &ids);
    let centres: Vec<_> = ids.iter().map(|i| rec.views[i].center()).collect();
    let (order, found) = handheld_dense::densify_order(&points, &centres);
    (order.into_iter().map(|i| ids[i]).collect(), found)
}

fn load_views(
    paths: &BTreeMap<String, PathBuf>,
    rec: &MetricReconstruction,
    ids: &[ImageId],
    set_size: usize,
    stage_opts: &DenseStageOptions,
) -> Result<Vec<PosedView>> {
    let opts = ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    ids.par_iter()
        .map(|id| {
            let view = &rec.views[id];
            let path = paths.get(&view.name).ok_or_else(|| PipelineError::Input {
                path: view.name.clone().into(),
                reason: "no such image among the inputs".into(),
            })?;
            let camera = rec.cameras.get(&view.camera_id).ok_or_else(|| {
                PipelineError::workspace(
                    &view.name,
                    "camera missing from the sparse model; rerun the sparse stage",
                )
            })?;
            let img = load_image(path, &opts)?.image.to_rgb8();
            if (img.width(), img.height()) != (camera.width, camera.height) {
                return Err(PipelineError::Input {
                    path: path.clone(),
                    reason: format!(
                        "image is {}x{} but the sparse model says {}x{} (rerun with --force)",
                        img.width(),
                        img.height(),
                        camera.width,
                        camera.height
                    ),
                });
            }
            let longer = img.width().max(img.height());
            let max_size = stage_opts.max_size_for(img.width(), img.height(), set_size);
            let (img, camera) = if max_size > 0 && longer > max_size {
                let s = max_size as f64 / longer as f64;
                let w = (img.width() as f64 * s).round() as u32;
                let h = (img.height() as f64 * s).round() as u32;
                let small =
                    image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
                let c = camera.scaled(
                    w as f64 / img.width() as f64,
                    h as f64 / img.height() as f64,
                );
                (small, c)
            } else {
                (img, camera.clone())
            };
            Ok(PosedView::new(
                view.name.clone(),
                camera,
                view.cam_from_world,
                img,
            ))
        })
        .collect()
}

/// Densifies the views `ids` of `rec` (images found through `paths`, by view name) into `dir`.
pub fn densify(
    rec: &MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    ids: &[ImageId],
    opts: &DenseStageOptions,
    dir: &Path,
    progress: &dyn Progress,
) -> Result<Produced<DenseStageSummary>> {
    densify_with(rec, paths, (ids, None), opts, dir, progress, |_| None)
}

/// [`densify`], with pairs matched elsewhere (`handheld_dense::dense_reconstruct_with`).
fn densify_with(
    rec: &MetricReconstruction,
    paths: &BTreeMap<String, PathBuf>,
    (ids, order): (&[ImageId], Option<SequenceOrder>),
    opts: &DenseStageOptions,
    dir: &Path,
    progress: &dyn Progress,
    matched: impl Fn(usize) -> Option<std::result::Result<PairDisparity, String>>,
) -> Result<Produced<DenseStageSummary>> {
    let views = load_views(paths, rec, ids, ids.len(), opts)?;
    if let (Some(v), Some(id)) = (views.first(), ids.first()) {
        let full = rec
            .views
            .get(id)
            .and_then(|view| rec.cameras.get(&view.camera_id))
            .map(|c| (c.width, c.height));
        let used = (v.image.width(), v.image.height());
        if let Some(full) = full.filter(|f| *f != used) {
            tracing::info!(
                "dense: {} views matched at {}x{} (the images are {}x{}; limits: --dense-max-size, \
                 --dense-max-megapixels, and {:.1} GB of memory for the views' maps)",
                ids.len(),
                used.0,
                used.1,
                full.0,
                full.1,
                opts.memory_budget_bytes() / 1e9
            );
        }
    }
    let points = SparsePoints::from_tracks(rec.points.values(), ids);
    for sub in MapKind::ALL
        .iter()
        .map(|k| k.dir_name())
        .chain([PREVIEW_DIR])
    {
        std::fs::create_dir_all(dir.join(sub))
            .map_err(|e| handheld_io::IoError::io(dir.join(sub), e))?;
    }
    let mut per_view = Vec::new();
    let mut outputs = Vec::new();
    let (cloud, summary) =
        dense_reconstruct_with(&views, &points, &opts.dense, progress, matched, |r| {
            let v = &r.view;
            let name = &v.name;
            let write = || -> Result<Vec<String>> {
                let written = write_view(dir, v)?;
                let pdir = dir.join(PREVIEW_DIR);
                for (map, kind) in [(&v.depth, "depth"), (&v.visibility, "visibility")] {
                    if let Some(map) = map {
                        write_preview(map, &pdir.join(format!("{name}.{kind}.png")))?;
                    }
                }
                Ok(written)
            };
            let written = write().map_err(|e| handheld_dense::DenseError::Linking {
                reason: format!("{name}: cannot write the maps: {e}"),
            })?;
            outputs.extend(written);
            tracing::info!(
                "dense: {name}: {:.1} % filled in {:.2} s",
                v.fill() * 100.0,
                r.seconds
            );
            per_view.push(ViewFill {
                image: name.clone(),
                width: v.posed.camera.width,
                height: v.posed.camera.height,
                fill: v.fill(),
                seconds: r.seconds,
            });
            Ok(())
        })
        .context("dense matching")?;
    handheld_io::ply::write_point_cloud(&dir.join(FUSED_PLY), &cloud, Default::default())?;
    // In the model's order (what readers list), whatever order the views were densified in.
    let mut by_id: Vec<(ImageId, &PosedView)> = ids.iter().copied().zip(&views).collect();
    by_id.sort_by_key(|(id, _)| *id);
    write_cameras(dir, by_id.into_iter().map(|(_, v)| v))?;
    let mut s = DenseStageSummary {
        views: summary.views,
        pairs_matched: summary.pairs_matched,
        polar_pairs: summary.polar_pairs,
        pairs_failed: summary
            .pairs_failed
            .iter()
            .map(|f| FailedPair {
                pair: [views[f.first].name.clone(), views[f.first + 1].name.clone()],
                reason: f.reason.clone(),
            })
            .collect(),
        fused_points: summary.fused_points,
        seconds_pairs: summary.seconds_pairs,
        seconds_linking: summary.seconds_linking,
        seconds_per_view: (summary.seconds_pairs + summary.seconds_linking)
            / summary.views.max(1) as f64,
        per_view: Some(per_view),
        sequence: order.clone(),
    };
    write_json(&dir.join(SUMMARY_JSON), &s)?;
    outputs.extend([FUSED_PLY.into(), CAMERAS_FILE.into(), SUMMARY_JSON.into()]);
    s.per_view = None;
    let warnings = order
        .filter(|o| o.broken > 0)
        .map(|o| {
            Warning::new(
                code::NOTE,
                format!(
                    "{} of the {} pairs of neighbouring views share fewer than {} sparse points \
                     with parallax: their depth is thin or missing",
                    o.broken,
                    ids.len().saturating_sub(1),
                    handheld_dense::MIN_RANGE_POINTS
                ),
            )
            .advice("add photos between the views that the summary's failed pairs name")
        })
        .into_iter()
        .collect();
    // `summary.json` (with the per-view figures) is written here, as `densify_model` needs it too.
    Ok(Produced::new(outputs, s)
        .summary_file(SummaryFile::Own)
        .warn(warnings))
}

/// The dense stage on any COLMAP model (text or binary) and the folder of its images, into `out`
/// (the layout of `WS/dense`).
pub fn densify_model(
    model: &Path,
    images: &Path,
    opts: &DenseStageOptions,
    out: &Path,
    progress: &dyn Progress,
) -> Result<DenseStageSummary> {
    opts.validate()?;
    let rec = handheld_io::colmap::read_reconstruction(model)?;
    let paths: BTreeMap<String, PathBuf> = rec
        .views
        .values()
        .map(|v| (v.name.clone(), images.join(&v.name)))
        .collect();
    let (ids, order) = sequence(&rec, rec.views.keys().copied().collect());
    std::fs::create_dir_all(out).map_err(|e| handheld_io::IoError::io(out, e))?;
    let (dir, none) = (out, |_| None);
    Ok(densify_with(&rec, &paths, (&ids, Some(order)), opts, dir, progress, none)?.summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_keep_their_size_until_the_megapixel_or_memory_limit() {
        let o = DenseStageOptions {
            max_memory_gb: 1.0,
            ..Default::default()
        };
        // Two 12 MP phone photos fit: their own size.
        assert_eq!(o.max_size_for(4032, 3024, 2), 0);
        // A hundred share 1 GB: 1e9 / (100 · 32) pixels each, about 645 px on the longer side.
        let s = o.max_size_for(4032, 3024, 100);
        let px = f64::from(s) * f64::from(s) * 3024.0 / 4032.0;
        let want = 1e9 / (100.0 * BYTES_PER_VIEW_PIXEL);
        assert!((px - want).abs() / px < 0.01, "{s}");
        // A 36 MP image is brought to 24 MP whatever the memory.
        let big = DenseStageOptions {
            max_memory_gb: 1000.0,
            ..Default::default()
        };
        let s = big.max_size_for(7360, 4912, 2);
        let px = f64::from(s) * f64::from(s) * 4912.0 / 7360.0;
        assert!((px - 24e6).abs() / 24e6 < 0.01, "{s}");
        // --dense-max-size wins when smaller.
        let small = DenseStageOptions {
            max_size: 1600,
            ..big
        };
        assert_eq!(small.max_size_for(7360, 4912, 2), 1600);
    }
}
