//! Conversions between protocol values and Python objects: vectors of reals travel as
//! little-endian `f64` bytes (numpy reads them with `np.frombuffer(b, "<f8")`).

use std::collections::BTreeMap;

use ciflow_bridge::protocol::F64s;
use ciflow_envs::{BoxSpace, Dtype, EnvSpec, ResetOptions};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

pub fn floats_from_bytes(what: &str, bytes: &[u8]) -> PyResult<Vec<f64>> {
    F64s::from_le_bytes(bytes).ok_or_else(|| {
        PyValueError::new_err(format!(
            "{what}: {} bytes is not a whole number of little-endian float64",
            bytes.len()
        ))
    })
}

pub fn floats_to_bytes<'py>(py: Python<'py>, values: &[f64]) -> Bound<'py, PyBytes> {
    PyBytes::new(py, &F64s::to_le_bytes(values))
}

pub fn columns_to_dict<'py>(
    py: Python<'py>,
    columns: &BTreeMap<String, Vec<f64>>,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (key, values) in columns {
        dict.set_item(key, floats_to_bytes(py, values))?;
    }
    Ok(dict)
}

fn space_to_dict<'py>(py: Python<'py>, space: &BoxSpace) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("low", space.low.clone())?;
    dict.set_item("high", space.high.clone())?;
    dict.set_item(
        "dtype",
        match space.dtype {
            Dtype::Float32 => "float32",
            Dtype::Float64 => "float64",
        },
    )?;
    Ok(dict)
}

pub fn spec_to_dict<'py>(py: Python<'py>, spec: &EnvSpec) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("id", &spec.id)?;
    dict.set_item(
        "observation_space",
        space_to_dict(py, &spec.observation_space)?,
    )?;
    dict.set_item("action_space", space_to_dict(py, &spec.action_space)?)?;
    dict.set_item("context_space", space_to_dict(py, &spec.context_space)?)?;
    dict.set_item("control_dt", spec.control_dt)?;
    dict.set_item("physics_dt", spec.physics_dt)?;
    dict.set_item("max_episode_steps", spec.max_episode_steps)?;
    Ok(dict)
}

/// Reset options as JSON (`{"context": [...], "initial_position": [...], "extra": {...}}`).
pub fn reset_options_from_json(json: Option<&str>) -> PyResult<Option<ResetOptions>> {
    json.map(|text| {
        serde_json::from_str(text)
            .map_err(|e| PyValueError::new_err(format!("bad reset options {text}: {e}")))
    })
    .transpose()
}
