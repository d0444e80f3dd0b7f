//! Demonstration datasets from Python: the Rust writer and reader of `ciflow demos`'s Minari
//! layout (`ciflow_envs::dataset`), the in-process expert recorder it runs, and the episode
//! channel's publisher. Vectors travel as little-endian `f64` bytes, rows concatenated.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Mutex;

use ciflow_bridge::EpisodePublisher;
use ciflow_bridge::error::full_message;
use ciflow_envs::dataset::{self, Credits, DatasetSpec, Episode};
use ciflow_envs::registry::Kwarg;
use ciflow_envs::rollout::{Recording, record_expert_dataset};
use ciflow_envs::{BoxSpace, Dtype};
use pyo3::exceptions::{PyFileExistsError, PyKeyError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::convert::{PyKwarg, floats_from_bytes, floats_to_bytes, kwargs_from_py, kwargs_to_dict};
use crate::errors::to_py;

fn dataset_error(error: dataset::DatasetError) -> PyErr {
    let message = full_message(&error);
    match error {
        dataset::DatasetError::AlreadyExists(_) | dataset::DatasetError::NotADataset(_) => {
            PyFileExistsError::new_err(message)
        }
        dataset::DatasetError::Io { .. } => PyOSError::new_err(message),
        _ => PyValueError::new_err(message),
    }
}

fn space_from_dict(spec: &Bound<'_, PyDict>, name: &str) -> PyResult<BoxSpace> {
    let space = spec
        .get_item(name)?
        .ok_or_else(|| PyKeyError::new_err(format!("spec has no `{name}`")))?;
    let low: Vec<f64> = space.get_item("low")?.extract()?;
    let high: Vec<f64> = space.get_item("high")?.extract()?;
    let dtype = match space.get_item("dtype")?.extract::<String>()?.as_str() {
        "float32" => Dtype::Float32,
        "float64" => Dtype::Float64,
        other => {
            return Err(PyValueError::new_err(format!(
                "{name}: dtype `{other}` is neither float32 nor float64"
            )));
        }
    };
    if low.len() != high.len() {
        return Err(PyValueError::new_err(format!(
            "{name}: {} lower and {} upper bounds",
            low.len(),
            high.len()
        )));
    }
    Ok(BoxSpace::new(low, high, dtype))
}

/// What every episode of a dataset shares: built from an environment's spec (the dict of
/// `CiflowEnv.task_spec`), its construction arguments and a Minari dataset id.
#[pyclass(name = "DatasetSpec", module = "ciflow._native", frozen)]
pub struct PyDatasetSpec {
    pub spec: DatasetSpec,
}

#[pymethods]
impl PyDatasetSpec {
    #[new]
    #[pyo3(signature = (env_spec, dataset_id, algorithm_name="expert", kwargs=None))]
    fn new(
        env_spec: &Bound<'_, PyDict>,
        dataset_id: &str,
        algorithm_name: &str,
        kwargs: Option<BTreeMap<String, PyKwarg>>,
    ) -> PyResult<Self> {
        dataset::check_dataset_id(dataset_id).map_err(dataset_error)?;
        let kwargs = kwargs_from_py(kwargs);
        let id: String = env_spec
            .get_item("id")?
            .ok_or_else(|| PyKeyError::new_err("spec has no `id`"))?
            .extract()?;
        let control_dt: f64 = env_spec
            .get_item("control_dt")?
            .ok_or_else(|| PyKeyError::new_err("spec has no `control_dt`"))?
            .extract()?;
        if !(control_dt.is_finite() && control_dt > 0.0) {
            return Err(PyValueError::new_err(format!(
                "control_dt {control_dt} is not a positive number"
            )));
        }
        Ok(Self {
            spec: DatasetSpec {
                dataset_id: dataset_id.to_owned(),
                env_id: id,
                env_kwargs: kwargs,
                observation_space: space_from_dict(env_spec, "observation_space")?,
                action_space: space_from_dict(env_spec, "action_space")?,
                context_space: space_from_dict(env_spec, "context_space")?,
                control_dt,
                algorithm_name: algorithm_name.to_owned(),
                credits: Credits::default(),
            },
        })
    }

    #[getter]
    fn dataset_id(&self) -> &str {
        &self.spec.dataset_id
    }

    #[getter]
    fn env_id(&self) -> &str {
        &self.spec.env_id
    }
}

/// One recorded episode of `T` steps, checked against its dataset's spec.
#[pyclass(name = "Episode", module = "ciflow._native", frozen)]
pub struct PyEpisode {
    episode: Episode,
}

/// `count` rows of `dim` values from `bytes` (f64, row-major).
fn rows(what: &str, bytes: &[u8], dim: usize, count: usize) -> PyResult<Vec<Vec<f64>>> {
    let values = floats_from_bytes(what, bytes)?;
    if values.len() != dim * count {
        return Err(PyValueError::new_err(format!(
            "{what}: {} values, expected {count} rows × {dim}",
            values.len()
        )));
    }
    Ok(match dim {
        0 => vec![Vec::new(); count],
        dim => values.chunks_exact(dim).map(<[f64]>::to_vec).collect(),
    })
}

#[pymethods]
impl PyEpisode {
    /// `T + 1` observations (the reset one first) and `T` actions and rewards, as f64
    /// bytes; `terminated`/`truncated` describe the last step; `infos` maps names to
    /// `T + 1` values each. Contexts are the observations' tails, as the engine lays them.
    #[new]
    #[pyo3(signature = (spec, seed, observations, actions, rewards, terminated, truncated, infos=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        spec: &PyDatasetSpec,
        seed: Option<u64>,
        observations: &[u8],
        actions: &[u8],
        rewards: &[u8],
        terminated: bool,
        truncated: bool,
        infos: Option<BTreeMap<String, Vec<u8>>>,
    ) -> PyResult<Self> {
        let spec = &spec.spec;
        let rewards = floats_from_bytes("rewards", rewards)?;
        let steps = rewards.len();
        if steps == 0 {
            return Err(PyValueError::new_err("an episode needs at least one step"));
        }
        let observations = rows(
            "observations",
            observations,
            spec.observation_space.dim(),
            steps + 1,
        )?;
        let context_dim = spec.context_space.dim();
        let contexts = observations
            .iter()
            .map(|o| o[o.len().saturating_sub(context_dim)..].to_vec())
            .collect();
        let flags = |last: bool| {
            let mut flags = vec![false; steps];
            flags[steps - 1] = last;
            flags
        };
        let infos = infos
            .unwrap_or_default()
            .into_iter()
            .map(|(name, bytes)| Ok((name.clone(), floats_from_bytes(&name, &bytes)?)))
            .collect::<PyResult<_>>()?;
        Ok(Self {
            episode: Episode {
                seed,
                observations,
                actions: rows("actions", actions, spec.action_space.dim(), steps)?,
                rewards,
                terminations: flags(terminated),
                truncations: flags(truncated),
                contexts,
                infos,
            },
        })
    }

    /// Number of steps `T`.
    fn __len__(&self) -> usize {
        self.episode.len()
    }
}

/// Writes a dataset in `ciflow demos`'s layout, atomically: episodes fill a hidden sibling
/// directory that `finish` renames into place (dropping an unfinished writer removes it).
#[pyclass(name = "DatasetWriter", module = "ciflow._native")]
pub struct PyDatasetWriter {
    writer: Mutex<Option<dataset::DatasetWriter>>,
}

#[pymethods]
impl PyDatasetWriter {
    #[new]
    #[pyo3(signature = (path, spec, overwrite=false))]
    fn new(path: PathBuf, spec: &PyDatasetSpec, overwrite: bool) -> PyResult<Self> {
        let writer = dataset::DatasetWriter::create(&path, spec.spec.clone(), overwrite)
            .map_err(dataset_error)?;
        Ok(Self {
            writer: Mutex::new(Some(writer)),
        })
    }

    /// Appends the next episode (validated against the spec: lengths, dimensions, NaN).
    fn append(&self, py: Python<'_>, episode: &PyEpisode) -> PyResult<()> {
        let mut writer = self.lock();
        let writer = writer
            .as_mut()
            .ok_or_else(|| PyRuntimeError::new_err("the dataset writer is finished"))?;
        py.detach(|| writer.append(&episode.episode))
            .map_err(dataset_error)
    }

    /// Writes the metadata and moves the dataset into place; returns its path.
    fn finish(&self, py: Python<'_>) -> PyResult<PathBuf> {
        let writer = self
            .lock()
            .take()
            .ok_or_else(|| PyRuntimeError::new_err("the dataset writer is finished"))?;
        py.detach(|| writer.finish()).map_err(dataset_error)
    }
}

impl PyDatasetWriter {
    fn lock(&self) -> std::sync::MutexGuard<'_, Option<dataset::DatasetWriter>> {
        self.writer.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// Publishes finished episodes on `ciflow/v2/episodes/<task>/<recorder>` (make it with
/// `ClientHandle.episode_publisher`).
#[pyclass(name = "EpisodePublisher", module = "ciflow._native")]
pub struct PyEpisodePublisher {
    pub publisher: Mutex<EpisodePublisher>,
    pub key: String,
}

#[pymethods]
impl PyEpisodePublisher {
    #[getter]
    fn key(&self) -> &str {
        &self.key
    }

    /// Publishes episode number `index` of the dataset `spec`.
    fn publish(
        &self,
        py: Python<'_>,
        index: u64,
        spec: &PyDatasetSpec,
        episode: &PyEpisode,
    ) -> PyResult<()> {
        let publisher = self.publisher.lock().unwrap_or_else(|p| p.into_inner());
        py.detach(|| publisher.publish(index, &spec.spec, &episode.episode))
            .map_err(to_py)
    }
}

fn space_to_py<'py>(py: Python<'py>, space: &BoxSpace) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("low", space.low.clone())?;
    dict.set_item("high", space.high.clone())?;
    Ok(dict)
}

/// Reads a dataset with the Rust reader: `(spec, episodes)` where `spec` holds
/// `dataset_id, env_id, env_kwargs, algorithm_name, control_dt` and the spaces, and each episode
/// `seed, observations, actions, rewards, contexts` (f64 bytes, rows concatenated),
/// `terminations, truncations` (one byte per step) and `infos` (name → f64 bytes).
#[pyfunction]
pub fn read_dataset<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Bound<'py, PyDict>, Vec<Bound<'py, PyDict>>)> {
    let (spec, episodes) = py.detach(|| dataset::read(&path)).map_err(dataset_error)?;
    let info = PyDict::new(py);
    info.set_item("dataset_id", &spec.dataset_id)?;
    info.set_item("env_id", &spec.env_id)?;
    info.set_item("env_kwargs", kwargs_to_dict(py, &spec.env_kwargs)?)?;
    info.set_item("algorithm_name", &spec.algorithm_name)?;
    info.set_item("control_dt", spec.control_dt)?;
    info.set_item(
        "observation_space",
        space_to_py(py, &spec.observation_space)?,
    )?;
    info.set_item("action_space", space_to_py(py, &spec.action_space)?)?;
    info.set_item("context_space", space_to_py(py, &spec.context_space)?)?;
    let flags = |v: &[bool]| PyBytes::new(py, &v.iter().map(|&b| u8::from(b)).collect::<Vec<_>>());
    let episodes = episodes
        .iter()
        .map(|e| {
            let dict = PyDict::new(py);
            dict.set_item("seed", e.seed)?;
            dict.set_item(
                "observations",
                floats_to_bytes(py, &e.observations.concat()),
            )?;
            dict.set_item("actions", floats_to_bytes(py, &e.actions.concat()))?;
            dict.set_item("rewards", floats_to_bytes(py, &e.rewards))?;
            dict.set_item("contexts", floats_to_bytes(py, &e.contexts.concat()))?;
            dict.set_item("terminations", flags(&e.terminations))?;
            dict.set_item("truncations", flags(&e.truncations))?;
            let infos = PyDict::new(py);
            for (name, series) in &e.infos {
                infos.set_item(name, floats_to_bytes(py, series))?;
            }
            dict.set_item("infos", infos)?;
            Ok(dict)
        })
        .collect::<PyResult<_>>()?;
    Ok((info, episodes))
}

/// Records the expert in this process exactly as `ciflow demos` does (same function);
/// returns the dataset id.
#[pyfunction]
#[pyo3(signature = (task, out, episodes, seed=0, kwargs=None, options=None, overwrite=false))]
#[allow(clippy::too_many_arguments)]
pub fn record_expert(
    py: Python<'_>,
    task: &str,
    out: PathBuf,
    episodes: u64,
    seed: u64,
    kwargs: Option<BTreeMap<String, PyKwarg>>,
    options: Option<BTreeMap<String, f64>>,
    overwrite: bool,
) -> PyResult<String> {
    let recording = Recording {
        task: task.to_owned(),
        kwargs: kwargs_from_py(kwargs),
        options: options.unwrap_or_default(),
        episodes,
        seed,
        dataset_id: None,
        credits: Credits::default(),
        format: Default::default(),
    };
    let spec = py
        .detach(|| record_expert_dataset(&recording, &out, overwrite, |_| {}))
        .map_err(|e| PyValueError::new_err(full_message(&e)))?;
    Ok(spec.dataset_id)
}

/// The number `text` stands for as reset option `key` of `task` (a number, or a name the
/// task gives its values, e.g. LASA's `shape=Sshape`).
/// Refuses reset `options` that contradict the construction arguments `kwargs` of the
/// same name ([`ciflow_envs::rollout::check_options_keep_kwargs`]).
#[pyfunction]
pub fn check_options_keep_kwargs(
    kwargs: BTreeMap<String, PyKwarg>,
    options: BTreeMap<String, f64>,
) -> PyResult<()> {
    ciflow_envs::rollout::check_options_keep_kwargs(&kwargs_from_py(Some(kwargs)), &options)
        .map_err(|e| PyValueError::new_err(full_message(&e)))
}

/// Refuses to replace `path` unless it is a dataset (or an empty directory) and
/// `overwrite` is set ([`dataset::check_replaceable`]).
#[pyfunction]
pub fn check_replaceable(path: PathBuf, overwrite: bool) -> PyResult<()> {
    dataset::check_replaceable(&path, overwrite).map_err(dataset_error)
}

#[pyfunction]
pub fn task_value(task: &str, key: &str, text: &str) -> PyResult<f64> {
    ciflow_envs::registry::entry(task)
        .and_then(|entry| entry.value(key, text))
        .map_err(|e| PyValueError::new_err(full_message(&e)))
}

/// Construction argument `key` of `task` given as `text`: a float as [`task_value`], or a
/// string for the arguments the task takes as text (a document argument such as the reach
/// task's `urdf` given as a path is read here, so the environment holds its content).
#[pyfunction]
pub fn task_argument<'py>(
    py: Python<'py>,
    task: &str,
    key: &str,
    text: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let argument = ciflow_envs::registry::entry(task)
        .and_then(|entry| entry.argument(key, text))
        .map_err(|e| PyValueError::new_err(full_message(&e)))?;
    Ok(match argument {
        Kwarg::Number(number) => number.into_pyobject(py)?.into_any(),
        Kwarg::Text(text) => text.into_pyobject(py)?.into_any(),
    })
}
