//! Split-and-merge structure from motion, for sets too large for one incremental run (issue #33),
//! after COLMAP's hierarchical mapper (Schönberger & Frahm 2016) and Bhowmick et al. 2014:
//!
//! 1. [`partition`]: the view graph cut into clusters of at most `cluster_views` views that overlap
//!    their neighbours (`partition.rs`);
//! 2. [`reconstruct_cluster`]: each cluster reconstructed on its own, with its own
//!    self-calibration, by the whole of [`crate::reconstruct`] (one task each: the Python package
//!    runs them on a Dask cluster, the library in parallel with rayon);
//! 3. [`merge_clusters`]: the models merged one by one into the largest, each by the similarity
//!    that maps its points onto the same keypoints of the views both registered (`merge.rs`),
//!    checked against the verified pairs across the cut, and then one global bundle adjustment of
//!    the whole, with the intrinsics shared per camera group.
//!
//! [`reconstruct_split`] does the three in one call; [`crate::reconstruct`] calls it when more
//! than [`SplitOptions::above`] photos have verified pairs. Video keeps the one incremental run
//! (its in-between frames hang on the key-frames' sequence).

mod merge;
mod partition;

use std::time::Instant;

use handheld_core::Progress;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::SfmError;
use crate::input::{SfmInput, SfmPair};
use crate::options::SfmOptions;
use crate::summary::SfmResult;

pub use merge::merge_clusters;
pub use partition::{partition, Cluster, DENSE_EIGEN_MAX};

/// When and how [`crate::reconstruct`] splits the view graph.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SplitOptions {
    /// Split when more photos than this have a verified pair; 0 never splits. Default 1000.
    pub above: usize,
    /// Most views in a cluster, its overlap included. Default 200.
    pub cluster_views: usize,
    /// Views a cluster borrows from its neighbours, as a fraction of its own (0.2–0.5 keeps
    /// enough common points for the merge). Default 0.3.
    pub overlap: f64,
}

impl Default for SplitOptions {
    fn default() -> Self {
        Self {
            above: 1000,
            cluster_views: 200,
            overlap: 0.3,
        }
    }
}

impl SplitOptions {
    /// The option that is out of range and why.
    pub fn invalid(&self) -> Option<(&'static str, String)> {
        if self.cluster_views < 8 {
            return Some((
                "split.cluster_views",
                format!("must be at least 8, got {}", self.cluster_views),
            ));
        }
        if !(self.overlap.is_finite() && (0.1..=1.0).contains(&self.overlap)) {
            return Some((
                "split.overlap",
                format!("must be between 0.1 and 1, got {}", self.overlap),
            ));
        }
        None
    }

    /// Whether `input` is split.
    pub fn applies(&self, input: &SfmInput) -> bool {
        self.above > 0 && !input.video && linked_images(input) > self.above
    }
}

/// Images with keypoints and at least one verified pair.
pub(crate) fn linked_images(input: &SfmInput) -> usize {
    let mut linked = vec![false; input.images.len()];
    for p in &input.pairs {
        if p.a < linked.len() && p.b < linked.len() && !p.matches.is_empty() {
            linked[p.a] = true;
            linked[p.b] = true;
        }
    }
    linked
        .iter()
        .zip(&input.images)
        .filter(|(l, im)| **l && !im.keypoints.is_empty())
        .count()
}

/// The input restricted to one cluster's views and the pairs between them (images keep their ids).
pub fn cluster_input(input: &SfmInput, cluster: &Cluster) -> SfmInput {
    let mut local = vec![usize::MAX; input.images.len()];
    for (k, &i) in cluster.views.iter().enumerate() {
        if i < local.len() {
            local[i] = k;
        }
    }
    let images = cluster
        .views
        .iter()
        .filter_map(|&i| input.images.get(i).cloned())
        .collect();
    let pairs = input
        .pairs
        .iter()
        .filter(|p| {
            p.a < local.len()
                && p.b < local.len()
                && local[p.a] != usize::MAX
                && local[p.b] != usize::MAX
        })
        .map(|p| SfmPair {
            a: local[p.a],
            b: local[p.b],
            ..p.clone()
        })
        .collect();
    SfmInput {
        images,
        pairs,
        video: input.video,
    }
}

/// One cluster reconstructed on its own (the whole of [`crate::reconstruct`], never split again).
pub fn reconstruct_cluster(
    input: &SfmInput,
    cluster: &Cluster,
    options: &SfmOptions,
    progress: &dyn Progress,
) -> Result<SfmResult, SfmError> {
    let mut opts = options.clone();
    opts.split.above = 0;
    crate::reconstruct(&cluster_input(input, cluster), &opts, progress)
}

/// Partition, clusters in parallel, merge: the three steps of the module in one call.
pub fn reconstruct_split(
    input: &SfmInput,
    options: &SfmOptions,
    progress: &dyn Progress,
) -> Result<SfmResult, SfmError> {
    options.validate()?;
    input.validate().map_err(SfmError::InvalidInput)?;
    let t = Instant::now();
    let s = &options.split;
    let clusters = partition(input, s.cluster_views, s.overlap);
    tracing::info!(
        "split-and-merge: {} views in {} clusters of at most {} views ({:.1} s)",
        linked_images(input),
        clusters.len(),
        s.cluster_views,
        t.elapsed().as_secs_f64()
    );
    progress.start("clusters", clusters.len() as u64);
    let results: Vec<(Result<SfmResult, SfmError>, f64)> = clusters
        .par_iter()
        .map(|c| {
            let t = Instant::now();
            let r = reconstruct_cluster(input, c, options, &handheld_core::NoProgress);
            progress.inc(1);
            (r, t.elapsed().as_secs_f64())
        })
        .collect();
    progress.finish();
    let outcomes = results
        .into_iter()
        .map(|(r, secs)| merge::ClusterOutcome::new(r.map_err(|e| e.to_string()), secs))
        .collect();
    merge_clusters(input, options, &clusters, outcomes, progress)
}

pub use merge::{ClusterOutcome, ClusterReport, SplitReport};

#[cfg(test)]
mod tests;
