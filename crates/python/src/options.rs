//! Options between Python and Rust: a dict in the JSON form the workspace manifests record
//! (`PipelineOptions` serialised), merged over the defaults so that a dict may name only what it
//! changes. An unknown key and a wrong value are `OptionsError`s naming the dotted path
//! (`sparse.seed`), as the CLI names its flags.

use handheld_pipeline::PipelineOptions;
use pyo3::prelude::*;
use serde_json::Value;

use crate::OptionsError;

/// The options a Python value stands for: `None` gives the defaults; a dict (or any mapping
/// pythonize reads) is merged key by key over them.
pub fn from_py(value: Option<&Bound<'_, PyAny>>) -> PyResult<PipelineOptions> {
    let Some(value) = value.filter(|v| !v.is_none()) else {
        return Ok(PipelineOptions::default());
    };
    let given: Value = pythonize::depythonize(value).map_err(|e| {
        OptionsError::new_err(format!(
            "options: expected a dict of JSON values (see handheld.default_options()), got {e}"
        ))
    })?;
    if !given.is_object() {
        return Err(OptionsError::new_err(
            "options: expected a dict (see handheld.default_options())",
        ));
    }
    from_json(given).map_err(OptionsError::new_err)
}

/// `given` merged over the defaults, then read as `PipelineOptions`; the error names the first
/// unknown key or wrong value by its dotted path.
pub fn from_json(given: Value) -> Result<PipelineOptions, String> {
    let mut merged = serde_json::to_value(PipelineOptions::default())
        .map_err(|e| format!("options: the defaults do not serialise ({e})"))?;
    merge(&mut merged, given);
    let mut unknown = Vec::new();
    let mut note = |path: serde_ignored::Path<'_>| unknown.push(path.to_string());
    let de = serde_ignored::Deserializer::new(merged, &mut note);
    let options: PipelineOptions = serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        format!("option `{path}`: {}", e.inner())
    })?;
    if let Some(key) = unknown.first() {
        return Err(format!(
            "option `{key}`: unknown (see handheld.default_options() for every option and its default)"
        ));
    }
    Ok(options)
}

/// Writes `given` into `base`, recursively for objects on both sides; anything else replaces.
fn merge(base: &mut Value, given: Value) {
    match (base, given) {
        // An enum's variant (serde's one-key map, `{"pixel_footprint": 3}`) given as another
        // variant (`{"absolute": 0.1}`) replaces it: the two cannot be merged.
        (Value::Object(b), Value::Object(g))
            if b.len() == 1 && g.len() == 1 && b.keys().next() != g.keys().next() =>
        {
            *b = g;
        }
        (Value::Object(b), Value::Object(g)) => {
            for (k, v) in g {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// Options as the dict `from_py` reads back.
pub fn to_py<'py>(py: Python<'py>, o: &PipelineOptions) -> PyResult<Bound<'py, PyAny>> {
    pythonize::pythonize(py, o).map_err(|e| OptionsError::new_err(e.to_string()))
}
