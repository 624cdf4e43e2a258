//! `handheld bench scale`: how the sparse stage grows with the number of views, monolithic
//! against split-and-merge (issue #33), on testkit's walk round a block (`testkit::street`:
//! exact truth, synthetic correspondences, no images). For each size: time, peak memory and the
//! pairwise relative-pose AUC against the truth (as `../shared/tools/eval_sfm.py` computes it),
//! and for each mode the exponent of a log–log fit of the time against the views.
//!
//! Peak memory is the process's resident high-water mark (`VmHWM`), reset before each run through
//! `/proc/self/clear_refs`; it includes what the allocator kept from the runs before, so it is an
//! upper bound. Both modes run on a thread pool of `workers` threads (the clusters in parallel).

use std::time::Instant;

use handheld_core::{ImageId, MetricReconstruction, NoProgress, Progress};
use handheld_robust::TwoViewConfiguration;
use handheld_sfm::{reconstruct, split, SfmImage, SfmInput, SfmOptions, SfmPair, SplitOptions};
use handheld_testkit::street::{street_set, StreetOptions};
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// Options of [`bench_scale`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScaleBenchOptions {
    /// The sizes, in views. Default 250, 500, 1000, 2000.
    pub views: Vec<usize>,
    /// The monolithic run is skipped above this many views. Default 2000.
    pub monolithic_max: usize,
    /// Split-and-merge's largest cluster. Default 200.
    pub cluster_views: usize,
    pub overlap: f64,
    /// About how many points a view sees. Default 300.
    pub points_per_view: usize,
    /// Threads of the pool both modes run on. Default 2.
    pub workers: usize,
    pub seed: u64,
}

impl Default for ScaleBenchOptions {
    fn default() -> Self {
        Self {
            views: vec![250, 500, 1000, 2000],
            monolithic_max: 2000,
            cluster_views: SplitOptions::default().cluster_views,
            overlap: SplitOptions::default().overlap,
            points_per_view: 300,
            workers: 2,
            seed: 0,
        }
    }
}

/// One run: a size and a mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScaleRun {
    pub views: usize,
    /// `monolithic` or `split`.
    pub mode: String,
    pub seconds: f64,
    pub peak_rss_mb: Option<f64>,
    /// Views in the largest model, and the models.
    pub registered: usize,
    pub models: usize,
    pub clusters: Option<usize>,
    /// Pairwise relative-pose AUC at 1° and 5° (percent; unregistered views count as wrong).
    pub auc1: f64,
    pub auc5: f64,
    /// Relative error of the focal length, percent.
    pub focal_error_pct: Option<f64>,
    /// Why the run gave no model.
    pub error: Option<String>,
    /// The largest model's step timings (`ModelSummary::timings_s`), and split-and-merge's
    /// merge and global adjustment.
    pub timings_s: std::collections::BTreeMap<String, f64>,
    /// Split-and-merge's report (clusters, merges, what stayed apart and why).
    pub split: Option<split::SplitReport>,
    /// The metric frames the largest model's stratified start tried (or the calibrated
    /// incremental starts), as `summary.json` lists them.
    #[serde(default)]
    pub candidates: Vec<handheld_sfm::CandidateRecord>,
}

/// The report: every run, and the growth of each mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScaleBenchReport {
    pub runs: Vec<ScaleRun>,
    /// Exponent `b` of `seconds ≈ a · views^b`, least squares in log–log, per mode.
    pub exponent_monolithic: Option<f64>,
    pub exponent_split: Option<f64>,
    /// At each size both modes ran: split's AUC@1 minus the monolithic one.
    pub auc1_gap: Vec<(usize, f64)>,
    pub workers: usize,
}

/// Runs the benchmark.
pub fn bench_scale(o: &ScaleBenchOptions, progress: &dyn Progress) -> Result<ScaleBenchReport> {
    if o.views.iter().any(|&n| n < 8) || o.views.is_empty() {
        return Err(EvalError::option(
            "--views",
            "each size must be at least 8 views",
        ));
    }
    if o.workers == 0 {
        return Err(EvalError::option("--workers", "must be at least 1"));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(o.workers)
        .build()
        .map_err(|e| EvalError::option("--workers", e.to_string()))?;
    let mut runs = Vec::new();
    progress.start("scale runs", (o.views.len() * 2) as u64);
    for &n in &o.views {
        let (input, truth) = street_input(&StreetOptions {
            num_views: n,
            points_per_view: o.points_per_view,
            seed: o.seed,
            ..Default::default()
        })
        .map_err(|e| EvalError::option("--views", e))?;
        for mode in ["monolithic", "split"] {
            progress.inc(1);
            if mode == "monolithic" && n > o.monolithic_max {
                continue;
            }
            let options = SfmOptions {
                seed: o.seed,
                split: SplitOptions {
                    above: if mode == "split" { 1 } else { 0 },
                    cluster_views: o.cluster_views,
                    overlap: o.overlap,
                },
                ..Default::default()
            };
            reset_peak_rss();
            let t = Instant::now();
            let result = pool.install(|| reconstruct(&input, &options, &NoProgress));
            let seconds = t.elapsed().as_secs_f64();
            let peak_rss_mb = peak_rss_mb();
            let run = scored(
                n,
                mode,
                seconds,
                peak_rss_mb,
                result.map_err(|e| e.to_string()),
                &truth,
            );
            tracing::info!(
                "{n} views, {mode}: {:.1} s, AUC@1 {:.2}, {} registered",
                run.seconds,
                run.auc1,
                run.registered
            );
            runs.push(run);
        }
    }
    progress.finish();
    let exponent = |mode: &str| {
        let pts: Vec<(f64, f64)> = runs
            .iter()
            .filter(|r| r.mode == mode && r.error.is_none())
            .map(|r| ((r.views as f64).ln(), r.seconds.max(1e-6).ln()))
            .collect();
        slope(&pts)
    };
    let auc1_gap = o
        .views
        .iter()
        .filter_map(|&n| {
            let of = |m: &str| runs.iter().find(|r| r.views == n && r.mode == m);
            Some((n, of("split")?.auc1 - of("monolithic")?.auc1))
        })
        .collect();
    Ok(ScaleBenchReport {
        exponent_monolithic: exponent("monolithic"),
        exponent_split: exponent("split"),
        auc1_gap,
        runs,
        workers: o.workers,
    })
}

/// A run scored against the truth.
fn scored(
    views: usize,
    mode: &str,
    seconds: f64,
    peak_rss_mb: Option<f64>,
    result: std::result::Result<handheld_sfm::SfmResult, String>,
    truth: &MetricReconstruction,
) -> ScaleRun {
    match result {
        Ok(r) => {
            let best = &r.models[0].reconstruction;
            let mut timings_s = r.models[0].summary.timings_s.clone();
            if let Some(sp) = &r.split {
                timings_s.insert("split_merge".into(), sp.merge_seconds);
                timings_s.insert(
                    "split_global_adjustment".into(),
                    sp.global_adjustment_seconds,
                );
                let c: f64 = sp.clusters.iter().map(|c| c.seconds).sum();
                timings_s.insert("split_clusters_cpu".into(), c);
            }
            let (auc1, auc5) = auc(best, truth);
            let f_true = truth.cameras.values().next().map(|c| c.intrinsics.f);
            let f = best.cameras.values().next().map(|c| c.intrinsics.f);
            ScaleRun {
                views,
                mode: mode.into(),
                seconds,
                peak_rss_mb,
                registered: best.views.len(),
                models: r.models.len(),
                clusters: r.split.as_ref().map(|s| s.clusters.len()),
                auc1,
                auc5,
                focal_error_pct: f.zip(f_true).map(|(f, t)| 100.0 * (f / t - 1.0).abs()),
                error: None,
                timings_s,
                split: r.split.clone(),
                candidates: r.models[0].summary.self_calibration.candidates.clone(),
            }
        }
        Err(e) => ScaleRun {
            views,
            mode: mode.into(),
            seconds,
            peak_rss_mb,
            registered: 0,
            models: 0,
            clusters: None,
            auc1: 0.0,
            auc5: 0.0,
            focal_error_pct: None,
            error: Some(e),
            timings_s: Default::default(),
            split: None,
            candidates: Vec::new(),
        },
    }
}

/// One size of the benchmark cut into its clusters, for a driver that runs the clusters
/// elsewhere (the Python package's `handheld.distributed.bench_scale`, on Dask). Every task
/// builds it again from the same options: the walk and the partition are deterministic.
pub struct ScaleProblem {
    pub views: usize,
    pub input: SfmInput,
    pub truth: MetricReconstruction,
    pub options: SfmOptions,
    pub clusters: Vec<split::Cluster>,
}

impl ScaleProblem {
    pub fn new(views: usize, o: &ScaleBenchOptions) -> Result<Self> {
        let (input, truth) = street_input(&StreetOptions {
            num_views: views,
            points_per_view: o.points_per_view,
            seed: o.seed,
            ..Default::default()
        })
        .map_err(|e| EvalError::option("views", e))?;
        let options = SfmOptions {
            seed: o.seed,
            split: SplitOptions {
                above: 1,
                cluster_views: o.cluster_views,
                overlap: o.overlap,
            },
            ..Default::default()
        };
        options
            .validate()
            .map_err(|e| EvalError::option("cluster_views", e.to_string()))?;
        let clusters = split::partition(&input, o.cluster_views, o.overlap);
        Ok(Self {
            views,
            input,
            truth,
            options,
            clusters,
        })
    }

    /// Cluster `k` reconstructed (one task).
    pub fn run_cluster(&self, k: usize) -> Result<split::ClusterOutcome> {
        let c = self.clusters.get(k).ok_or_else(|| {
            EvalError::option("k", format!("no cluster {k} of {}", self.clusters.len()))
        })?;
        let t = Instant::now();
        let r = split::reconstruct_cluster(&self.input, c, &self.options, &NoProgress);
        Ok(split::ClusterOutcome::new(
            r.map_err(|e| e.to_string()),
            t.elapsed().as_secs_f64(),
        ))
    }

    /// The clusters' outcomes merged and scored; `seconds` is the time the driver measured.
    pub fn merge(
        &self,
        outcomes: Vec<split::ClusterOutcome>,
        seconds: f64,
        mode: &str,
    ) -> ScaleRun {
        let t = Instant::now();
        let r = split::merge_clusters(
            &self.input,
            &self.options,
            &self.clusters,
            outcomes,
            &NoProgress,
        );
        let seconds = seconds + t.elapsed().as_secs_f64();
        scored(
            self.views,
            mode,
            seconds,
            peak_rss_mb(),
            r.map_err(|e| e.to_string()),
            &self.truth,
        )
    }
}

/// The walk as the SfM input: keypoints are the noisy observations, pairs the window's.
pub fn street_input(
    opts: &StreetOptions,
) -> std::result::Result<(SfmInput, MetricReconstruction), String> {
    let set = street_set(opts)?;
    let images = set
        .truth
        .views
        .values()
        .map(|v| {
            let cam = &set.truth.cameras[&v.camera_id];
            SfmImage {
                id: v.id,
                name: v.name.clone(),
                width: cam.width,
                height: cam.height,
                keypoints: v.observations.iter().map(|o| o.xy).collect(),
                keypoint_scales: Vec::new(),
                camera_key: "street".into(),
                focal_prior_px: None,
                frame: None,
                track_ids: Vec::new(),
                descriptors: Vec::new(),
                descriptor_dim: 0,
            }
        })
        .collect();
    let pairs = set
        .pairs
        .into_iter()
        .map(|p| SfmPair {
            a: p.a,
            b: p.b,
            matches: p.matches,
            f: Some(p.f),
            configuration: TwoViewConfiguration::General,
            view_distance_px: None,
        })
        .collect();
    let input = SfmInput {
        images,
        pairs,
        video: false,
    };
    Ok((input, set.truth))
}

/// Pairwise relative-pose AUC at 1° and 5° over every pair of views of the truth, as
/// `eval_sfm.py` computes it: the error of a pair is the larger of its relative rotation's and
/// its translation direction's; a pair with a view not in `est` is wrong.
pub fn auc(est: &MetricReconstruction, truth: &MetricReconstruction) -> (f64, f64) {
    let ids: Vec<ImageId> = truth.views.keys().copied().collect();
    let mut errors = Vec::with_capacity(ids.len() * ids.len().saturating_sub(1) / 2);
    for (k, a) in ids.iter().enumerate() {
        for b in &ids[k + 1..] {
            let (Some(ea), Some(eb)) = (est.views.get(a), est.views.get(b)) else {
                errors.push(f64::INFINITY);
                continue;
            };
            let (ga, gb) = (&truth.views[a], &truth.views[b]);
            let rel = |x: &handheld_core::View, y: &handheld_core::View| {
                let r = y.cam_from_world.rotation * x.cam_from_world.rotation.inverse();
                let t = y.cam_from_world.rotation * (x.center() - y.center());
                (r, t)
            };
            let (re, te) = rel(ea, eb);
            let (rg, tg) = rel(ga, gb);
            let rot = (rg.inverse() * re).angle().to_degrees();
            let cos = te.dot(&tg) / (te.norm() * tg.norm() + 1e-300);
            let dir = cos.clamp(-1.0, 1.0).acos().to_degrees();
            errors.push(rot.max(dir));
        }
    }
    errors.sort_by(f64::total_cmp);
    (auc_at(&errors, 1.0), auc_at(&errors, 5.0))
}

/// The area under the recall curve of sorted `errors` up to `th`, percent.
fn auc_at(errors: &[f64], th: f64) -> f64 {
    let n = errors.len() as f64;
    if errors.is_empty() {
        return 0.0;
    }
    let (mut area, mut prev_e, mut prev_r) = (0.0, 0.0, 0.0);
    for (k, &e) in errors.iter().enumerate() {
        if e > th {
            break;
        }
        let r = (k + 1) as f64 / n;
        area += (e - prev_e) * (prev_r + r) / 2.0;
        prev_e = e;
        prev_r = r;
    }
    area += (th - prev_e) * prev_r;
    100.0 * area / th
}

/// Least-squares slope of `(x, y)` points; `None` with fewer than two distinct `x`.
fn slope(pts: &[(f64, f64)]) -> Option<f64> {
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 1e-12).then(|| sxy / sxx)
}

pub(crate) fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

pub(crate) fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

impl ScaleBenchReport {
    /// The report in a few lines, for people (the CLI prints it without `--json`).
    pub fn summary_text(&self) -> String {
        let mut s = String::from(
            "views  mode        seconds  peak MB  registered  AUC@1  AUC@5  f err %\n",
        );
        for x in &self.runs {
            s += &format!(
                "{:>5}  {:<10}  {:>7.1}  {:>7.0}  {:>10}  {:>5.2}  {:>5.2}  {}\n",
                x.views,
                x.mode,
                x.seconds,
                x.peak_rss_mb.unwrap_or(f64::NAN),
                x.registered,
                x.auc1,
                x.auc5,
                x.focal_error_pct.map_or("-".into(), |f| format!("{f:.2}")),
            );
        }
        s += &format!(
            "time ~ views^b: monolithic b = {}, split b = {}",
            self.exponent_monolithic
                .map_or("-".into(), |b| format!("{b:.2}")),
            self.exponent_split
                .map_or("-".into(), |b| format!("{b:.2}"))
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_auc_matches_eval_sfm_on_a_known_curve() {
        // Errors 0.5 and 0.5 of four pairs, two wrong: recall 0.5 from 0.5° on.
        let e = [0.5, 0.5, f64::INFINITY, f64::INFINITY];
        // Trapezoid (0,0)→(0.5,0.25)→(0.5,0.5), then flat at 0.5 to 1°: 0.0625 + 0.25.
        assert!((auc_at(&e, 1.0) - 31.25).abs() < 1e-9);
        assert!((slope(&[(0.0, 1.0), (1.0, 2.3), (2.0, 3.6)]).unwrap() - 1.3).abs() < 1e-12);
    }

    #[test]
    fn the_truth_scores_a_hundred() {
        let (_, truth) = street_input(&StreetOptions {
            num_views: 30,
            points_per_view: 50,
            ..Default::default()
        })
        .unwrap();
        let (a1, a5) = auc(&truth, &truth);
        assert!(a1 > 99.99 && a5 > 99.99, "{a1} {a5}");
    }
}
