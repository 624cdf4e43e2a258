//! The Python package `handheld` (module `handheld._handheld`, re-exported by
//! `python/handheld/__init__.py`): the pipeline library called from Python, and a workspace's
//! files read into numpy arrays. Nothing here computes; every call goes to the pipeline library or
//! to `handheld-io`, as the CLI's do.
//!
//! - [`options`]: a Python dict ↔ `PipelineOptions`, the same JSON as the workspace manifests, with
//!   an unknown key or a wrong value named by its dotted path;
//! - [`progress`]: a Python callable as the pipeline's `Progress`;
//! - [`workspace`]: `Workspace` and `SparseModel`: summaries, the COLMAP model, depth maps and the
//!   mesh as numpy arrays;
//! - errors: `HandheldError` with the CLI's message, `OptionsError` (a subclass) for options.

use std::path::PathBuf;

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

mod bench;
mod options;
mod progress;
mod workspace;

create_exception!(
    handheld,
    HandheldError,
    PyException,
    "A Handheld error: the message is the command line's, naming the file, option or stage and saying what to do."
);
create_exception!(
    handheld,
    OptionsError,
    HandheldError,
    "An unknown option, or an option whose value is of the wrong type or out of its range; the message names it by its dotted path."
);

/// The message the CLI prints after `error: ` (the error and its causes, as anyhow's `{:#}`).
pub(crate) fn message(e: impl Into<anyhow::Error>) -> String {
    format!("{:#}", e.into())
}

/// A pipeline error as the Python exception of its kind.
pub(crate) fn to_py(e: impl Into<handheld_pipeline::PipelineError>) -> PyErr {
    let e = e.into();
    if e.invalid_option().is_some() {
        OptionsError::new_err(message(e))
    } else {
        HandheldError::new_err(message(e))
    }
}

/// Runs the standard graph on `input` (a photo folder or a video) into `workspace`, up to `until`
/// (a stage name; the whole graph when None), like `handheld reconstruct`: the same stages and the
/// same files, resuming where an earlier run stopped (`force` reruns every stage).
///
/// `options` is a dict in the JSON form of the workspace manifests (see `default_options()`); keys
/// left out keep their defaults. `progress(step, done, total)` is called from worker threads while
/// the GIL is released (`total` is 0 when unknown). Returns one dict per stage: `stage`, `status`
/// (`ran` or `skipped`), `seconds`, `summary`, `warnings`.
#[pyfunction]
#[pyo3(signature = (input, workspace, options=None, until=None, force=false, progress=None))]
fn reconstruct<'py>(
    py: Python<'py>,
    input: PathBuf,
    workspace: PathBuf,
    options: Option<&Bound<'py, PyAny>>,
    until: Option<String>,
    force: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let options = options::from_py(options)?;
    validate(&input, &options)?;
    let bar = progress::PyProgress::new(progress);
    let result = py.detach(|| {
        handheld_pipeline::reconstruct(&input, &workspace, &options, until.as_deref(), force, &bar)
    });
    bar.raise_callback_error()?;
    let reports = result.map_err(to_py)?;
    pythonize::pythonize(py, &reports).map_err(|e| HandheldError::new_err(e.to_string()))
}

/// Every option with its default, as the dict `reconstruct` takes (the JSON of the manifests).
#[pyfunction]
fn default_options(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    options::to_py(py, &handheld_pipeline::PipelineOptions::default())
}

/// The complete options a dict stands for (defaults filled in), after the same checks as
/// `reconstruct` makes; raises `OptionsError` naming an unknown key or a wrong value.
#[pyfunction]
#[pyo3(signature = (options=None))]
fn check_options<'py>(
    py: Python<'py>,
    options: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let o = options::from_py(options)?;
    validate(std::path::Path::new(""), &o)?;
    options::to_py(py, &o)
}

/// The range checks every stage makes on its options when the graph is built; any failure there
/// is the options' fault.
fn validate(input: &std::path::Path, o: &handheld_pipeline::PipelineOptions) -> PyResult<()> {
    handheld_pipeline::Pipeline::standard(input, o)
        .map(|_| ())
        .map_err(|e| OptionsError::new_err(message(e)))
}

/// The standard graph for `input` with these options (checked).
fn pipeline(
    input: &std::path::Path,
    options: Option<&Bound<'_, PyAny>>,
) -> PyResult<handheld_pipeline::Pipeline> {
    let o = options::from_py(options)?;
    handheld_pipeline::Pipeline::standard(input, &o).map_err(|e| OptionsError::new_err(message(e)))
}

/// The graph (as `pipeline`) and the workspace it runs in.
fn graph_and_workspace(
    input: &std::path::Path,
    workspace: &std::path::Path,
    options: Option<&Bound<'_, PyAny>>,
) -> PyResult<(handheld_pipeline::Pipeline, handheld_pipeline::Workspace)> {
    let p = pipeline(input, options)?;
    let ws = handheld_pipeline::Workspace::open(workspace).map_err(to_py)?;
    Ok((p, ws))
}

/// The stages a run up to `until` runs, in order: `(name, reads, required)`, where `reads` are
/// the stages it needs and `required` is false for a stage the target only uses when present.
/// (The distributed driver's plan; `handheld.distributed`.)
#[pyfunction]
#[pyo3(signature = (input, options=None, until=None))]
fn plan(
    input: PathBuf,
    options: Option<&Bound<'_, PyAny>>,
    until: Option<String>,
) -> PyResult<Vec<(String, Vec<String>, bool)>> {
    let p = pipeline(&input, options)?;
    let (names, required): (Vec<&str>, Vec<&str>) = match &until {
        Some(t) => (p.plan(t).map_err(to_py)?, p.required(t).map_err(to_py)?),
        None => (p.names(), p.names()),
    };
    Ok(names
        .into_iter()
        .map(|n| {
            (
                n.to_string(),
                p.reads(n).into_iter().map(String::from).collect(),
                required.contains(&n),
            )
        })
        .collect())
}

/// The number of work units `stage` splits into in `workspace` (0: it does not split, or it is
/// up to date and `force` is false). The stages it reads must have run.
#[pyfunction]
#[pyo3(signature = (input, workspace, stage, options=None, force=false))]
fn stage_units(
    py: Python<'_>,
    input: PathBuf,
    workspace: PathBuf,
    stage: String,
    options: Option<&Bound<'_, PyAny>>,
    force: bool,
) -> PyResult<usize> {
    let (p, ws) = graph_and_workspace(&input, &workspace, options)?;
    py.detach(|| p.units(&ws, &stage, force)).map_err(to_py)
}

/// Runs unit `k` of `stage` (files written atomically, the unit's marker last; nothing when the
/// unit is done already, so a retried task is harmless).
#[pyfunction]
#[pyo3(signature = (input, workspace, stage, k, options=None))]
fn run_unit(
    py: Python<'_>,
    input: PathBuf,
    workspace: PathBuf,
    stage: String,
    k: usize,
    options: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let (p, ws) = graph_and_workspace(&input, &workspace, options)?;
    py.detach(|| p.run_unit(&ws, &stage, k, &handheld_core::NoProgress))
        .map_err(to_py)
}

/// Runs one stage unless it is up to date, taking the files of its units that ran apart; returns
/// its report (as `reconstruct` returns them).
#[pyfunction]
#[pyo3(signature = (input, workspace, stage, options=None, force=false, progress=None))]
fn run_stage<'py>(
    py: Python<'py>,
    input: PathBuf,
    workspace: PathBuf,
    stage: String,
    options: Option<&Bound<'py, PyAny>>,
    force: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let (p, ws) = graph_and_workspace(&input, &workspace, options)?;
    let bar = progress::PyProgress::new(progress);
    let report = py.detach(|| p.run_stage(&ws, &stage, force, &bar));
    bar.raise_callback_error()?;
    pythonize::pythonize(py, &report.map_err(to_py)?)
        .map_err(|e| HandheldError::new_err(e.to_string()))
}

/// Writes `workspace/report.html` from whatever stages exist (as `reconstruct` does at its end);
/// returns its path.
#[pyfunction]
fn write_report(py: Python<'_>, workspace: PathBuf) -> PyResult<PathBuf> {
    let ws = handheld_pipeline::Workspace::open(&workspace).map_err(to_py)?;
    py.detach(|| handheld_pipeline::write_report(&ws))
        .map(|r| r.html)
        .map_err(to_py)
}

#[pymodule]
fn _handheld(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("HandheldError", py.get_type::<HandheldError>())?;
    m.add("OptionsError", py.get_type::<OptionsError>())?;
    m.add("__version__", handheld_pipeline::HANDHELD_VERSION)?;
    m.add(
        "STAGES",
        handheld_pipeline::Pipeline::standard(
            std::path::Path::new(""),
            &handheld_pipeline::PipelineOptions::default(),
        )
        .map_err(to_py)?
        .names(),
    )?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(default_options, m)?)?;
    m.add_function(wrap_pyfunction!(check_options, m)?)?;
    m.add_function(wrap_pyfunction!(plan, m)?)?;
    m.add_function(wrap_pyfunction!(stage_units, m)?)?;
    m.add_function(wrap_pyfunction!(run_unit, m)?)?;
    m.add_function(wrap_pyfunction!(run_stage, m)?)?;
    m.add_function(wrap_pyfunction!(bench::scale_clusters, m)?)?;
    m.add_function(wrap_pyfunction!(bench::scale_cluster, m)?)?;
    m.add_function(wrap_pyfunction!(bench::scale_merge, m)?)?;
    m.add_function(wrap_pyfunction!(write_report, m)?)?;
    m.add_class::<workspace::Workspace>()?;
    m.add_class::<workspace::SparseModel>()?;
    Ok(())
}
