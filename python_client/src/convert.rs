//! Conversions between protocol values and Python objects: vectors of reals travel as
//! little-endian `f64` bytes (numpy reads them with `np.frombuffer(b, "<f8")`).

use std::collections::BTreeMap;

use ciflow_bridge::protocol::{F64s, PerturbationKindMsg, PerturbationMsg};
use ciflow_envs::registry::{Kwarg, Kwargs};
use ciflow_envs::{BoxSpace, Dtype, EnvSpec, ResetOptions};
use pyo3::conversion::FromPyObjectOwned;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyByteArray, PyBytes, PyDict};

/// A construction argument from Python: a number (`obstacles=2`) or a string (a URDF).
#[derive(FromPyObject)]
pub enum PyKwarg {
    Number(f64),
    Text(String),
}

/// Construction arguments from Python (absent: none).
pub fn kwargs_from_py(kwargs: Option<BTreeMap<String, PyKwarg>>) -> Kwargs {
    kwargs
        .unwrap_or_default()
        .into_iter()
        .map(|(name, value)| {
            let kwarg = match value {
                PyKwarg::Number(number) => Kwarg::Number(number),
                PyKwarg::Text(text) => Kwarg::Text(text),
            };
            (name, kwarg)
        })
        .collect()
}

/// Construction arguments as a Python dict of floats and strings.
pub fn kwargs_to_dict<'py>(py: Python<'py>, kwargs: &Kwargs) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (name, kwarg) in kwargs {
        match kwarg {
            Kwarg::Number(number) => dict.set_item(name, number)?,
            Kwarg::Text(text) => dict.set_item(name, text)?,
        }
    }
    Ok(dict)
}

pub fn floats_from_bytes(what: &str, bytes: &[u8]) -> PyResult<Vec<f64>> {
    F64s::from_le_bytes(bytes).ok_or_else(|| {
        PyValueError::new_err(format!(
            "{what}: {} bytes is not a whole number of little-endian float64",
            bytes.len()
        ))
    })
}

pub fn floats_to_bytes<'py>(py: Python<'py>, values: &[f64]) -> Bound<'py, PyBytes> {
    PyBytes::new(py, &F64s::le_bytes(values))
}

/// `values` as little-endian `f64` bytes in a new `bytearray`, for arrays handed to the
/// caller: `np.frombuffer` reads a `bytearray` in place and writable, where `bytes` would
/// need a second copy to be writable. A batch reset and the info columns come back this
/// way; a batch step's other results are written into their `bytearray`s from the reply
/// itself (`step_batches`).
pub fn floats_to_bytearray<'py>(
    py: Python<'py>,
    values: &[f64],
) -> PyResult<Bound<'py, PyByteArray>> {
    PyByteArray::new_with(py, size_of_val(values), |bytes| {
        bytes.copy_from_slice(&F64s::le_bytes(values));
        Ok(())
    })
}

/// Info columns by key, each as [`floats_to_bytearray`].
pub fn columns_to_dict<'py>(
    py: Python<'py>,
    columns: &BTreeMap<String, Vec<f64>>,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (key, values) in columns {
        dict.set_item(key, floats_to_bytearray(py, values)?)?;
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

/// `dict[key]` as `T`, if present and not `None`; a clear error names `what` and the key.
fn field<'py, T: FromPyObjectOwned<'py>>(
    dict: &Bound<'py, PyDict>,
    what: &str,
    key: &str,
) -> PyResult<Option<T>> {
    match dict.get_item(key)? {
        Some(value) if !value.is_none() => value.extract::<T>().map(Some).map_err(|e| {
            let error: PyErr = e.into();
            PyValueError::new_err(format!("{what}: `{key}` has the wrong type: {error}"))
        }),
        _ => Ok(None),
    }
}

/// Reset options from a dict: `context`, `initial_position` and `initial_velocity`
/// (sequences of numbers), `extra` (a dict of numbers) and any other key a task-specific
/// number, folded into `extra`.
pub fn reset_options_from_dict(
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<Option<ResetOptions>> {
    let Some(options) = options else {
        return Ok(None);
    };
    const WHAT: &str = "reset options";
    let mut extra: BTreeMap<String, f64> = field(options, WHAT, "extra")?.unwrap_or_default();
    for (key, value) in options.iter() {
        let key: String = key.extract()?;
        if ["context", "initial_position", "initial_velocity", "extra"].contains(&key.as_str())
            || value.is_none()
        {
            continue;
        }
        let number = value.extract::<f64>().map_err(|_| {
            PyValueError::new_err(format!("{WHAT}: `{key}` must be a number, got {value}"))
        })?;
        extra.insert(key, number);
    }
    Ok(Some(ResetOptions {
        context: field(options, WHAT, "context")?,
        initial_position: field(options, WHAT, "initial_position")?,
        initial_velocity: field(options, WHAT, "initial_velocity")?,
        extra,
    }))
}

/// A perturbation from a dict: `{"kind": "joint_torque", "torque", "duration", "start"?}`
/// or `{"kind": "link_wrench", "link", "force", "torque"?, "duration", "start"?}`
/// (bridge/PROTOCOL.md; `start` in simulated seconds since the reset, absent: now).
pub fn perturbation_from_dict(perturbation: &Bound<'_, PyDict>) -> PyResult<PerturbationMsg> {
    const WHAT: &str = "perturbation";
    let required = |key: &str| PyValueError::new_err(format!("{WHAT}: `{key}` is required"));
    let kind: String = field(perturbation, WHAT, "kind")?.ok_or_else(|| required("kind"))?;
    let kind = match kind.as_str() {
        "joint_torque" => PerturbationKindMsg::JointTorque {
            torque: field(perturbation, WHAT, "torque")?.ok_or_else(|| required("torque"))?,
        },
        "link_wrench" => PerturbationKindMsg::LinkWrench {
            link: field(perturbation, WHAT, "link")?.ok_or_else(|| required("link"))?,
            force: field(perturbation, WHAT, "force")?.ok_or_else(|| required("force"))?,
            torque: field(perturbation, WHAT, "torque")?.unwrap_or([0.0; 3]),
        },
        other => {
            return Err(PyValueError::new_err(format!(
                "{WHAT}: kind `{other}` is neither `joint_torque` nor `link_wrench`"
            )));
        }
    };
    Ok(PerturbationMsg {
        kind,
        start: field(perturbation, WHAT, "start")?,
        duration: field(perturbation, WHAT, "duration")?.ok_or_else(|| required("duration"))?,
    })
}
