//! The dense stage (paper §4) over a whole sequence: every adjacent pair is rectified and
//! matched once, every view is linked through its neighbours (eq. 28, Kalman fusion), and the
//! linked depths are merged into one coloured point cloud.
//!
//! Pairs are computed lazily in a sliding window of `2·max_links` pairs around the current
//! reference view, so memory stays bounded for long sequences.

use std::time::Instant;

use handheld_core::{PointCloud, PosedView, Progress};
use nalgebra::{Point3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{DenseError, Result};
use crate::link::{link_depth, LinkOptions, LinkedDepth};
use crate::pair::{match_pair_with, PairDisparity, PairOptions};
use crate::sparse_points::SparsePoints;
use crate::stereo::StereoMatcher;

/// Options of [`dense_reconstruct`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DenseOptions {
    /// Rectification and matching of each adjacent pair.
    pub pair: PairOptions,
    /// Multi-view linking of each view through its neighbours.
    pub link: LinkOptions,
    /// Pixel stride of the fused point cloud.
    pub fused_stride: usize,
    /// A fused point is skipped when an earlier view's depth map already holds it within this
    /// relative depth difference.
    pub fused_duplicate_tolerance: f64,
}

impl Default for DenseOptions {
    fn default() -> Self {
        Self {
            pair: PairOptions::default(),
            link: LinkOptions::default(),
            fused_stride: 2,
            fused_duplicate_tolerance: 0.01,
        }
    }
}

impl DenseOptions {
    /// Checks every option; the error names the first offending one.
    pub fn validate(&self) -> Result<()> {
        self.pair.stereo.validate()?;
        self.pair.rectify.validate()?;
        self.link.validate()?;
        if self.fused_stride == 0 {
            return Err(DenseError::InvalidOption {
                option: "fused_stride",
                reason: "must be at least 1".into(),
            });
        }
        Ok(())
    }
}

/// The result for one reference view.
#[derive(Clone, Debug)]
pub struct DenseViewResult {
    /// Index of the view in the input sequence.
    pub index: usize,
    /// The input view (its image copied) with `depth`, `variance`, `confidence`
    /// ([`LinkedDepth::confidence`]) and `visibility` filled.
    pub view: PosedView,
    /// Seconds spent on this view (its share of pair matching plus linking).
    pub seconds: f64,
}

/// A pair of adjacent views that could not be rectified or matched.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FailedPair {
    /// The pair's first view (the second is `first + 1`).
    pub first: usize,
    /// Why it failed.
    pub reason: String,
}

/// What happened to the whole sequence.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DenseSummary {
    /// Views densified.
    pub views: usize,
    /// Adjacent pairs rectified and matched.
    pub pairs_matched: usize,
    /// Pairs that could not be rectified or matched, with the reason.
    pub pairs_failed: Vec<FailedPair>,
    /// Pairs rectified with polar rectification.
    pub polar_pairs: usize,
    /// Points in the fused cloud.
    pub fused_points: usize,
    /// Seconds spent rectifying and matching pairs.
    pub seconds_pairs: f64,
    /// Seconds spent linking.
    pub seconds_linking: f64,
}

/// Depth of every view of a sequence (each view's camera, pose and image are read; its maps are
/// ignored). `points` are the sparse points (for disparity ranges, [`SparsePoints::for_pair`]),
/// their observers given as positions in `views`. `on_view` receives each
/// view's result as soon as it is ready (to be written out), and the fused cloud is returned with
/// the summary.
pub fn dense_reconstruct(
    views: &[PosedView],
    points: &SparsePoints,
    opts: &DenseOptions,
    progress: &dyn Progress,
    on_view: impl FnMut(DenseViewResult) -> Result<()>,
) -> Result<(PointCloud, DenseSummary)> {
    dense_reconstruct_with(views, points, opts, progress, |_| None, on_view)
}

/// [`dense_reconstruct`], with the pairs matched elsewhere: `matched(p)` gives the outcome of the
/// pair `(p, p + 1)` when it was matched already (by [`crate::match_pair`] with `opts.pair` and
/// `points.for_pair(p, p + 1)`, on another machine: a failure as its message), and `None` to
/// match it here. The result is the same either way.
pub fn dense_reconstruct_with(
    views: &[PosedView],
    points: &SparsePoints,
    opts: &DenseOptions,
    progress: &dyn Progress,
    matched: impl Fn(usize) -> Option<std::result::Result<PairDisparity, String>>,
    mut on_view: impl FnMut(DenseViewResult) -> Result<()>,
) -> Result<(PointCloud, DenseSummary)> {
    opts.validate()?;
    if views.len() < 2 {
        return Err(DenseError::Linking {
            reason: format!(
                "dense matching needs at least 2 registered views, got {}",
                views.len()
            ),
        });
    }
    for v in views {
        v.check_image().map_err(|e| DenseError::Linking {
            reason: e.to_string(),
        })?;
    }
    let n = views.len();
    let links = opts.link.max_links.max(1);
    let mut pairs: Vec<Option<PairDisparity>> = vec![None; n - 1];
    let mut computed = vec![false; n - 1];
    let mut summary = DenseSummary {
        views: n,
        ..Default::default()
    };
    let mut matcher = StereoMatcher::new(opts.pair.stereo.clone())?;
    let mut cloud = PointCloud::default();
    let mut recent: Vec<(usize, LinkedDepth)> = Vec::new();
    progress.start("dense", n as u64);
    for k in 0..n {
        let t0 = Instant::now();
        let lo = k.saturating_sub(links);
        let hi = (k + links).min(n - 1);
        for p in lo..hi {
            if computed[p] {
                continue;
            }
            computed[p] = true;
            let (a, b) = (&views[p], &views[p + 1]);
            let tp = Instant::now();
            let outcome = matched(p).unwrap_or_else(|| {
                match_pair_with(&mut matcher, a, b, &points.for_pair(p, p + 1), &opts.pair)
                    .map_err(|e| e.to_string())
            });
            match outcome {
                Ok(pd) => {
                    summary.pairs_matched += 1;
                    summary.polar_pairs += usize::from(pd.rectification.is_polar());
                    pairs[p] = Some(pd);
                }
                Err(e) => {
                    tracing::warn!("dense: pair {} – {} skipped: {e}", a.name, b.name);
                    summary.pairs_failed.push(FailedPair {
                        first: p,
                        reason: e,
                    });
                }
            }
            summary.seconds_pairs += tp.elapsed().as_secs_f64();
        }
        // Pairs left of the window are no longer needed.
        for p in pairs.iter_mut().take(lo) {
            *p = None;
        }
        let tl = Instant::now();
        let linked = link_depth(views, &pairs, k, &opts.link)?;
        summary.seconds_linking += tl.elapsed().as_secs_f64();
        append_fused(&mut cloud, &views[k], &linked, &recent, views, opts);
        recent.retain(|(i, _)| i + links > k);
        recent.push((k, linked.clone()));
        let confidence = linked.confidence();
        let LinkedDepth {
            depth,
            variance,
            visibility,
        } = linked;
        let v = &views[k];
        let seconds = t0.elapsed().as_secs_f64();
        on_view(DenseViewResult {
            index: k,
            view: PosedView {
                name: v.name.clone(),
                posed: v.posed.clone(),
                image: v.image.clone(),
                depth: Some(depth),
                variance: Some(variance),
                confidence: Some(confidence),
                visibility: Some(visibility),
            },
            seconds,
        })?;
        progress.inc(1);
    }
    progress.finish();
    summary.fused_points = cloud.len();
    Ok((cloud, summary))
}

/// Adds a view's linked depths to the fused cloud, skipping points an earlier view's depth map
/// already holds (so each surface patch appears about once).
fn append_fused(
    cloud: &mut PointCloud,
    view: &PosedView,
    linked: &LinkedDepth,
    recent: &[(usize, LinkedDepth)],
    views: &[PosedView],
    opts: &DenseOptions,
) {
    let world_from_cam = view.posed.cam_from_world.inverse();
    let (w, h) = (linked.depth.width, linked.depth.height);
    let s = opts.fused_stride;
    for y in (0..h).step_by(s) {
        for x in (0..w).step_by(s) {
            let z = linked.depth.get(x, y, 0);
            if !(z.is_finite() && z > 0.0) {
                continue;
            }
            let n = view
                .posed
                .camera
                .intrinsics
                .pixel_to_normalized(Vector2::new(x as f64, y as f64));
            let pc = Vector3::new(n.x, n.y, 1.0) * f64::from(z);
            let pw = world_from_cam.transform_point(&Point3::from(pc));
            let seen_before = recent.iter().any(|(i, d)| {
                let o = &views[*i];
                o.posed.project(&pw).is_some_and(|m| {
                    let (xi, yi) = (m.x.round(), m.y.round());
                    if xi < 0.0
                        || yi < 0.0
                        || xi >= d.depth.width as f64
                        || yi >= d.depth.height as f64
                    {
                        return false;
                    }
                    let zo = d.depth.get(xi as usize, yi as usize, 0);
                    let zp = o.posed.cam_from_world.transform_point(&pw).z;
                    zo.is_finite()
                        && ((f64::from(zo) - zp) / zp).abs() < opts.fused_duplicate_tolerance
                })
            });
            if seen_before {
                continue;
            }
            cloud
                .positions
                .push([pw.x as f32, pw.y as f32, pw.z as f32]);
            cloud.colors.push(view.rgb(x as u32, y as u32));
        }
    }
}
