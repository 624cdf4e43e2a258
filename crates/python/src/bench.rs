//! The scale benchmark's pieces for a Dask driver (`handheld.distributed.bench_scale`): a size of
//! testkit's walk cut into clusters, one cluster reconstructed (a task: its outcome as bytes), and
//! the outcomes merged and scored. Each call builds the walk again from the same options (it is
//! deterministic), so a task needs nothing but its arguments.

use handheld_eval::bench::scale::{ScaleBenchOptions, ScaleProblem};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use crate::HandheldError;

fn problem(
    views: usize,
    points_per_view: usize,
    cluster_views: usize,
    overlap: f64,
    seed: u64,
) -> PyResult<ScaleProblem> {
    let o = ScaleBenchOptions {
        views: vec![views],
        cluster_views,
        overlap,
        points_per_view,
        seed,
        ..Default::default()
    };
    ScaleProblem::new(views, &o).map_err(|e| HandheldError::new_err(e.to_string()))
}

/// The number of clusters of a walk of `views` views.
#[pyfunction]
#[pyo3(signature = (views, points_per_view=300, cluster_views=200, overlap=0.3, seed=0))]
pub fn scale_clusters(
    py: Python<'_>,
    views: usize,
    points_per_view: usize,
    cluster_views: usize,
    overlap: f64,
    seed: u64,
) -> PyResult<usize> {
    py.detach(|| problem(views, points_per_view, cluster_views, overlap, seed))
        .map(|p| p.clusters.len())
}

/// Cluster `k` reconstructed; its outcome as bytes (postcard).
#[pyfunction]
#[pyo3(signature = (views, k, points_per_view=300, cluster_views=200, overlap=0.3, seed=0))]
#[allow(clippy::too_many_arguments)]
pub fn scale_cluster<'py>(
    py: Python<'py>,
    views: usize,
    k: usize,
    points_per_view: usize,
    cluster_views: usize,
    overlap: f64,
    seed: u64,
) -> PyResult<Bound<'py, PyBytes>> {
    let bytes = py.detach(|| -> PyResult<Vec<u8>> {
        let p = problem(views, points_per_view, cluster_views, overlap, seed)?;
        let o = p
            .run_cluster(k)
            .map_err(|e| HandheldError::new_err(e.to_string()))?;
        postcard::to_stdvec(&o).map_err(|e| HandheldError::new_err(e.to_string()))
    })?;
    Ok(PyBytes::new(py, &bytes))
}

/// The outcomes merged and scored against the truth: the benchmark's run as a dict (`seconds`
/// is the driver's time so far, the merge's is added).
#[pyfunction]
#[pyo3(signature = (views, outcomes, seconds, points_per_view=300, cluster_views=200, overlap=0.3, seed=0))]
#[allow(clippy::too_many_arguments)]
pub fn scale_merge<'py>(
    py: Python<'py>,
    views: usize,
    outcomes: Vec<Vec<u8>>,
    seconds: f64,
    points_per_view: usize,
    cluster_views: usize,
    overlap: f64,
    seed: u64,
) -> PyResult<Bound<'py, PyAny>> {
    let run = py.detach(|| -> PyResult<_> {
        let p = problem(views, points_per_view, cluster_views, overlap, seed)?;
        let outcomes = outcomes
            .iter()
            .map(|b| postcard::from_bytes(b))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| {
                HandheldError::new_err(format!("a cluster's outcome does not decode: {e}"))
            })?;
        Ok(p.merge(outcomes, seconds, "split-dask"))
    })?;
    pythonize::pythonize(py, &run).map_err(|e| HandheldError::new_err(e.to_string()))
}
