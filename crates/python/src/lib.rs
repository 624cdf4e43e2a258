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
pub(crate) fn to_py(e: handheld_pipeline::PipelineError) -> PyErr {
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
        handheld_pipeline::reconstruct(
            &input,
            &workspace,
            &options,
            until.as_deref(),
            force,
            &bar,
        )
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
    m.add_class::<workspace::Workspace>()?;
    m.add_class::<workspace::SparseModel>()?;
    Ok(())
}
