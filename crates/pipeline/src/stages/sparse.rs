//! The sparse stage (§3, Table 2 and §3.4): reads the features and verified pairs, runs
//! uncalibrated structure and motion (`handheld_sfm::reconstruct`), colours the points from the
//! images, and writes `sparse/`: the largest model as a COLMAP text + binary model, `points.ply`
//! and `summary.json`; further models (a broken sequence) under `sparse/models/<k>/`.

use std::path::Path;

use handheld_core::{MetricReconstruction, PointCloud, Progress};
use handheld_features::refine::{KeypointRefinementOptions, RefinementSummary};
use handheld_sfm::{reconstruct, split, DuplicateShot, ModelSummary, SfmInput, SfmOptions};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Context, PipelineError, Result};
use crate::files::{stage, write_json, COLMAP_MODEL_FILES, MODELS_DIR, POINTS_PLY, SUMMARY_JSON};
use crate::policy::{focal_verdict, FocalVerdict};
use crate::stage::{Produced, Stage, StageContext, SummaryFile};
use crate::warning::{code, Warning};

mod gaps;
mod input;
pub use input::load_input;
use input::{colorize, load_input_and_colours, refine_input};

/// Options of the sparse stage: keypoint refinement (photos), then SfM.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct SparseStageOptions {
    pub sfm: SfmOptions,
    /// Multi-view keypoint refinement before SfM; `None` keeps the detected positions. Video (KLT
    /// tracks, already registered to their first appearance) never uses it.
    pub refine_keypoints: Option<KeypointRefinementOptions>,
}

impl SparseStageOptions {
    pub fn validate(&self) -> Result<()> {
        self.sfm
            .validate()
            .map_err(|e| PipelineError::invalid(stage::SPARSE, e))?;
        if let Some(r) = &self.refine_keypoints {
            r.validate()
                .map_err(|e| PipelineError::invalid("keypoint refinement", e))?;
        }
        Ok(())
    }
}

/// The clusters of split-and-merge, in the stage's unit folder, and one cluster's outcome.
const CLUSTERS_FILE: &str = "clusters.plan";

fn cluster_file(k: usize) -> String {
    format!("cluster-{k}.bin")
}

/// One cluster reconstructed, timed, as a serialisable outcome.
fn run_cluster(
    input: &SfmInput,
    cluster: &split::Cluster,
    options: &SfmOptions,
    progress: &dyn Progress,
) -> split::ClusterOutcome {
    let t = std::time::Instant::now();
    let r = split::reconstruct_cluster(input, cluster, options, progress);
    split::ClusterOutcome::new(r.map_err(|e| e.to_string()), t.elapsed().as_secs_f64())
}

impl Sparse {
    /// Whether the input is split into clusters (never with keypoint refinement, which needs
    /// every image at once).
    fn splits(&self, input: &SfmInput) -> bool {
        self.options.refine_keypoints.is_none() && self.options.sfm.split.applies(input)
    }

    /// The clusters, from the unit folder when a distributed run wrote them.
    fn clusters(&self, ctx: &StageContext, input: &SfmInput) -> Vec<split::Cluster> {
        let planned = ctx
            .units
            .as_ref()
            .and_then(|u| std::fs::read(u.join(CLUSTERS_FILE)).ok())
            .and_then(|b| postcard::from_bytes(&b).ok());
        planned.unwrap_or_else(|| {
            let s = &self.options.sfm.split;
            split::partition(input, s.cluster_views, s.overlap)
        })
    }

    /// The clusters (those reconstructed apart taken from their units, the others here, in
    /// parallel), merged.
    fn split_and_merge(
        &self,
        ctx: &StageContext,
        dir: &Path,
        input: &SfmInput,
    ) -> Result<handheld_sfm::SfmResult> {
        let opts = &self.options.sfm;
        opts.validate()
            .map_err(|e| PipelineError::invalid(stage::SPARSE, e))?;
        let clusters = self.clusters(ctx, input);
        let mut outcomes: Vec<Option<split::ClusterOutcome>> = Vec::new();
        for k in 0..clusters.len() {
            let name = cluster_file(k);
            outcomes.push(match ctx.take_unit(k, std::slice::from_ref(&name), dir)? {
                Some(_) => crate::stage::read_unit_outcome(&dir.join(&name)),
                None => None,
            });
        }
        let missing = outcomes.iter().filter(|o| o.is_none()).count() as u64;
        tracing::info!(
            "split-and-merge: {} clusters of at most {} views, {} reconstructed here",
            clusters.len(),
            opts.split.cluster_views,
            missing
        );
        ctx.progress.start("clusters", missing);
        let outcomes: Vec<split::ClusterOutcome> = outcomes
            .into_par_iter()
            .zip(clusters.par_iter())
            .map(|(o, c)| {
                o.unwrap_or_else(|| {
                    let o = run_cluster(input, c, opts, &handheld_core::NoProgress);
                    ctx.progress.inc(1);
                    o
                })
            })
            .collect();
        ctx.progress.finish();
        split::merge_clusters(input, opts, &clusters, outcomes, ctx.progress)
            .context("structure from motion (split-and-merge)")
    }
}

/// An image left out of the model, with the reason.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Unregistered {
    pub image: String,
    pub reason: String,
}

/// What the sparse stage built (the largest model; `sparse/summary.json` has everything).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SparseSummary {
    pub models: usize,
    pub registered: usize,
    pub total_images: usize,
    pub points: usize,
    pub mean_reprojection_error_px: f64,
    pub focal_px: Vec<f64>,
    pub self_calibration_degenerate: Option<String>,
    pub unregistered: Vec<Unregistered>,
}

/// `sparse/summary.json` (and `sparse/models/<k>/summary.json`): a model's full summary.
#[derive(Clone, Debug, Serialize)]
pub struct SparseModelReport<'a> {
    #[serde(flatten)]
    pub model: &'a ModelSummary,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub keypoint_refinement: Option<RefinementReport>,
    /// The largest model only: the images left out, and the other models' summaries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unregistered: Option<&'a [Unregistered]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub other_models: Option<Vec<&'a ModelSummary>>,
    /// The largest model only: photos that repeat another (no point is made from such a pair
    /// alone).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duplicates: Option<&'a [DuplicateShot]>,
    /// The largest model only: what split-and-merge did, when the input was split.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub split: Option<&'a split::SplitReport>,
}

/// What keypoint refinement did, and in how long.
#[derive(Clone, Debug, Serialize)]
pub struct RefinementReport {
    #[serde(flatten)]
    pub summary: RefinementSummary,
    pub seconds: f64,
}

/// The sparse stage.
pub struct Sparse {
    pub options: SparseStageOptions,
}

impl Stage for Sparse {
    type Options = SparseStageOptions;
    type Summary = SparseSummary;

    const NAME: &'static str = stage::SPARSE;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::FEATURES, stage::MATCHES];
    const ABOUT: &'static str =
        "uncalibrated structure and motion with self-calibration (§3); writes the COLMAP model";

    fn options(&self) -> &SparseStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    /// Split-and-merge: one unit per cluster (`handheld_sfm::split`), when the input is split.
    fn units(&self, ctx: &StageContext) -> Result<usize> {
        let input = load_input(ctx.ws)?;
        if !self.splits(&input) {
            return Ok(0);
        }
        let s = &self.options.sfm.split;
        let clusters = split::partition(&input, s.cluster_views, s.overlap);
        if let Some(units) = &ctx.units {
            let bytes = postcard::to_stdvec(&clusters).map_err(|e| {
                PipelineError::Graph(format!("sparse: the clusters do not serialise: {e}"))
            })?;
            handheld_io::atomic::write_bytes_atomic(&units.join(CLUSTERS_FILE), &bytes)?;
        }
        Ok(clusters.len())
    }

    fn run_unit(
        &self,
        ctx: &StageContext,
        dir: &Path,
        k: usize,
    ) -> Result<(Vec<String>, serde_json::Value)> {
        let input = load_input(ctx.ws)?;
        let clusters = self.clusters(ctx, &input);
        let Some(cluster) = clusters.get(k) else {
            return Err(PipelineError::Graph(format!(
                "sparse: no cluster {k} ({} clusters)",
                clusters.len()
            )));
        };
        let outcome = run_cluster(&input, cluster, &self.options.sfm, ctx.progress);
        let summary = serde_json::json!({
            "views": cluster.views.len(),
            "registered": outcome.models.first().map_or(0, |m| m.0.views.len()),
            "error": outcome.error,
        });
        let name = cluster_file(k);
        let bytes = postcard::to_stdvec(&outcome).map_err(|e| {
            PipelineError::Graph(format!(
                "sparse: cluster {k}'s model does not serialise: {e}"
            ))
        })?;
        handheld_io::atomic::write_bytes_atomic(&dir.join(&name), &bytes)?;
        Ok((vec![name], summary))
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<SparseSummary>> {
        let ws = ctx.ws;
        let opts = &self.options.sfm;
        let (mut input, colours) = load_input_and_colours(ws)?;
        let refinement = match &self.options.refine_keypoints {
            Some(r) if !input.video => {
                let t0 = std::time::Instant::now();
                let s = refine_input(ws, &mut input, r, ctx.progress)?;
                let seconds = t0.elapsed().as_secs_f64();
                tracing::info!(
                    "keypoint refinement: {} of {} keypoints moved (median {:.2} px) in {seconds:.1} s",
                    s.moved,
                    s.attempted,
                    s.median_shift_px,
                );
                Some(RefinementReport {
                    summary: s,
                    seconds,
                })
            }
            _ => None,
        };
        let mut result = if self.splits(&input) {
            self.split_and_merge(ctx, dir, &input)?
        } else {
            reconstruct(&input, opts, ctx.progress).context("structure from motion")?
        };
        for m in result.models.iter_mut() {
            colorize(ws, &mut m.reconstruction, &colours)?;
        }
        let unregistered: Vec<Unregistered> = result
            .unregistered
            .iter()
            .map(|(n, why)| Unregistered {
                image: n.clone(),
                reason: why.clone(),
            })
            .collect();
        let mut outputs: Vec<String> = COLMAP_MODEL_FILES.iter().map(|f| f.to_string()).collect();
        outputs.extend([POINTS_PLY.into(), SUMMARY_JSON.into()]);
        for (k, m) in result.models.iter().enumerate() {
            let report = SparseModelReport {
                model: &m.summary,
                keypoint_refinement: refinement.clone(),
                unregistered: (k == 0).then_some(unregistered.as_slice()),
                other_models: (k == 0)
                    .then(|| result.models[1..].iter().map(|m| &m.summary).collect()),
                duplicates: (k == 0 && !result.duplicates.is_empty())
                    .then_some(result.duplicates.as_slice()),
                split: if k == 0 { result.split.as_ref() } else { None },
            };
            if k == 0 {
                write_model(dir, &m.reconstruction, &report)?;
            } else {
                let sub = dir.join(MODELS_DIR).join(k.to_string());
                write_model(&sub, &m.reconstruction, &report)?;
                outputs.push(format!("{MODELS_DIR}/{k}"));
            }
        }
        let names: Vec<String> = input.images.iter().map(|im| im.name.clone()).collect();
        let mut warnings = gaps::unregistered_warnings(&names, &unregistered);
        if result.models.len() > 1 {
            let members: Vec<Vec<usize>> = result
                .models
                .iter()
                .map(|m| {
                    let held: std::collections::BTreeSet<&str> = m
                        .reconstruction
                        .views
                        .values()
                        .map(|v| v.name.as_str())
                        .collect();
                    (0..names.len())
                        .filter(|&i| held.contains(names[i].as_str()))
                        .collect()
                })
                .collect();
            warnings.push(gaps::separate_models_warning(&names, &members));
        }
        let copies: Vec<String> = result
            .duplicates
            .iter()
            .filter(|d| d.identical)
            .map(|d| format!("{} and {}", d.image, d.of))
            .collect();
        if !copies.is_empty() {
            warnings.push(
                Warning::new(
                    code::DUPLICATE_PHOTOS,
                    format!(
                        "{} (the same pixels under two names): a copy adds nothing, and no point was made from a photo and its copy alone",
                        if copies.len() == 1 {
                            "1 photo appears twice".to_string()
                        } else {
                            format!("{} photos appear twice", copies.len())
                        }
                    ),
                )
                .advice("remove one of each pair from the input folder")
                .details(copies.join("; ")),
            );
        }
        if let Some(r) = &result.split {
            let f: Vec<f64> = r.clusters.iter().filter_map(|c| c.focal_px).collect();
            let (lo, hi) = f
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            if f.len() >= 2 && hi > 1.1 * lo {
                warnings.push(
                    Warning::new(
                        code::SPLIT_DISAGREEMENT,
                        format!("the clusters' own self-calibrations disagree on the focal length ({lo:.0}–{hi:.0} px): the merged model's focal length rests on the global adjustment"),
                    )
                    .advice("give the calibration with --intrinsics if it is known, or larger clusters (--cluster-views)")
                    .details("sparse/summary.json, split.clusters"),
                );
            }
            if !r.inconsistent_views.is_empty() {
                warnings.push(
                    Warning::new(
                        code::SPLIT_DISAGREEMENT,
                        format!(
                            "{} views of the merged model disagree with their verified pairs",
                            r.inconsistent_views.len()
                        ),
                    )
                    .details(r.inconsistent_views.join(", ")),
                );
            }
        }
        let best = &result.models[0].summary;
        for m in best.merged.iter().filter(|m| m.cross_pairs == 0) {
            warnings.push(Warning::new(
                code::UNCONFIRMED_MERGE,
                format!(
                    "{} views were merged into the model through their shared points alone: no verified pair between the two pieces was strong enough to confirm how they were put together",
                    m.views_added
                ),
            )
            .details("sparse/summary.json, merged"));
        }
        let alone = &best.view_consistency.unconfirmed;
        if !alone.is_empty() {
            warnings.push(
                Warning::new(
                    code::UNCONFIRMED_VIEWS,
                    format!(
                        "no verified pair confirms the pose of {}: the only views it could be checked against were taken out of the model as misplaced, and it may be misplaced too",
                        if alone.len() <= 4 {
                            alone.join(", ")
                        } else {
                            format!("{} views (listed in the details)", alone.len())
                        }
                    ),
                )
                .advice("add photos between them and the rest of the scene, or check them in the report")
                .details(alone.join(", ")),
            );
        }
        for g in best.groups.iter().filter(|g| g.principal_point_outside()) {
            // First, like the next: it is about the whole model.
            warnings.insert(
                0,
                Warning::new(
                    code::MODEL_DOUBTFUL,
                    format!(
                        "the model puts the principal point of camera {} at ({:.0}, {:.0}) px, outside its {}×{} images, where no camera's lies: its calibration (f = {:.0} px, k1 = {:.3}), and the poses adjusted with it, are not to be trusted",
                        g.camera_id, g.pp[0], g.pp[1], g.width, g.height, g.f, g.k1
                    ),
                )
                .advice("give the calibration with --intrinsics FX,FY,CX,CY if it is known, and add photos that overlap more; check the cameras in the report")
                .details("sparse/summary.json, groups and self_calibration.principal_point_spread"),
            );
        }
        if let Some(n) = best.view_consistency.misplaced_majority(best.registered) {
            // First: it is about the whole model, which the images' own warnings above are not.
            warnings.insert(
                0,
                Warning::new(
                    code::MODEL_DOUBTFUL,
                    format!(
                        "{n} views were placed where their own verified image pairs disagree, more than the {} the model kept: those were placed the same way from the same matches, so the model may be wrong as a whole",
                        best.registered
                    ),
                )
                .advice("check the cameras in the report; give the calibration with --intrinsics if it is known, and add photos that overlap more")
                .details("sparse/summary.json, view_consistency"),
            );
        }
        let kept = best
            .self_calibration
            .candidates
            .iter()
            .find(|c| c.accepted)
            .map_or("", |c| c.source.as_str());
        // Candidates that failed a check. A sound candidate that lost on its score is no warning,
        // nor are failed fallbacks when the self-calibrated (or given) frame was kept: the model
        // came from its first choice. Otherwise one warning names the first failure and counts
        // the rest; every candidate is in summary.json (`self_calibration.candidates`).
        let failed: Vec<_> = best
            .self_calibration
            .candidates
            .iter()
            .filter(|c| c.tried && !c.probe && !c.sound)
            .filter_map(|c| c.rejected.as_ref().map(|why| (c.source.as_str(), why)))
            .collect();
        for (source, why) in &failed {
            tracing::info!("the metric frame from {source} was rejected ({why})");
        }
        // A calibrated incremental model was built because no stratified frame was sound: its
        // own rejected starts are no warning (the kept one passed every check).
        let first_choice = matches!(kept, "self-calibration" | "known calibration")
            || best.self_calibration.calibrated_incremental;
        if best.self_calibration.calibrated_incremental {
            tracing::info!(
                "the model was built by calibrated incremental reconstruction ({kept}): no stratified metric frame was sound, or the one kept explained the images less well (sparse/summary.json, self_calibration.candidates)"
            );
        }
        if let (Some((source, why)), false) = (failed.first(), first_choice) {
            let mut details = format!("{source}: {why}");
            let others = failed.len() - 1;
            if others > 0 {
                let (n, verb) = if others == 1 {
                    ("1 other candidate".to_string(), "was")
                } else {
                    (format!("{others} other candidates"), "were")
                };
                details.push_str(&format!(
                    "; {n} {verb} rejected too; each, with its reason and score, is in sparse/summary.json under self_calibration.candidates"
                ));
            }
            warnings.push(
                Warning::new(
                    code::METRIC_FRAME_REJECTED,
                    format!("the metric frame from {source} failed its checks; the model uses the frame from {kept}"),
                )
                .details(details),
            );
        }
        match focal_verdict(best, opts.known_intrinsics.is_some()) {
            FocalVerdict::Calibrated => {}
            FocalVerdict::WellDetermined(note) => tracing::info!("{note}"),
            FocalVerdict::Doubtful(w) => warnings.push(w),
        }
        Ok(Produced::new(
            outputs,
            SparseSummary {
                models: result.models.len(),
                registered: best.registered,
                total_images: best.total_images,
                points: best.points,
                mean_reprojection_error_px: best.mean_reprojection_error_px,
                focal_px: best.groups.iter().map(|g| g.f).collect(),
                self_calibration_degenerate: best.self_calibration.degenerate.clone(),
                unregistered,
            },
        )
        .warn(warnings)
        .summary_file(SummaryFile::Own))
    }
}

fn write_model(dir: &Path, rec: &MetricReconstruction, summary: &SparseModelReport) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| handheld_io::IoError::io(dir, e))?;
    handheld_io::colmap::write_reconstruction(dir, rec, true, true)?;
    let cloud = PointCloud {
        positions: rec
            .points
            .values()
            .map(|p| [p.xyz.x as f32, p.xyz.y as f32, p.xyz.z as f32])
            .collect(),
        colors: rec.points.values().map(|p| p.color).collect(),
        normals: Vec::new(),
    };
    handheld_io::ply::write_point_cloud(&dir.join(POINTS_PLY), &cloud, Default::default())?;
    write_json(&dir.join(SUMMARY_JSON), summary)
}
