//! Python extension `ciflow._native` (built by maturin): the Rust Zenoh client and the
//! embedded engine. Every call that waits on the network releases the GIL. The
//! `gymnasium.Env` classes live in the pure-Python package `ciflow`.

mod convert;
mod datasets;
mod errors;
mod scenes;

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use ciflow_bridge::{
    ANY_ENGINE, BatchSeeds, BatchStepOut, Client, EngineServer, EpisodePublisher, Mode,
    NetworkOptions, RemoteEnv, ServerOptions, SessionControl, TelemetryStream, spread, vector,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyByteArray, PyBytes, PyDict};

use crate::convert::{
    PyKwarg, columns_to_dict, floats_from_bytes, floats_to_bytearray, floats_to_bytes,
    kwargs_from_py, kwargs_to_dict, perturbation_from_dict, reset_options_from_dict, spec_to_dict,
};
use crate::datasets::{PyDatasetSpec, PyDatasetWriter, PyEpisode, PyEpisodePublisher};
use crate::errors::{CiflowError, EngineUnreachable, to_py};

/// The extension's own allocations (requests, decoded replies, the arrays handed to numpy)
/// come from mimalloc, not from the Python process's glibc `malloc`. A batched step
/// allocates and frees a few hundred KiB in the Python thread; glibc gave those pages back
/// to the kernel at the end of each step (its heap trim) and faulted them in again at the
/// next: 89–91 page faults per step of 4 096 limit-cycle environments and 217 for
/// obstacles, about half of the client's CPU per step. mimalloc keeps freed pages for
/// reuse a while before it returns them: 0.1 faults per step (README, "Python").
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn network_options(
    config: Option<String>,
    mode: Option<&str>,
    connect: Option<Vec<String>>,
    listen: Option<Vec<String>>,
    identity: Option<String>,
) -> PyResult<NetworkOptions> {
    Ok(NetworkOptions {
        identity,
        config_file: config.map(Into::into),
        mode: mode
            .map(|m| m.parse::<Mode>())
            .transpose()
            .map_err(|e| PyValueError::new_err(e.to_string()))?,
        connect: connect.unwrap_or_default(),
        listen: listen.unwrap_or_default(),
    })
}

/// An engine running inside this process, announced on Zenoh like `ciflow serve`.
#[pyclass(module = "ciflow._native")]
struct Engine {
    server: Mutex<Option<EngineServer>>,
    name: String,
}

#[pymethods]
impl Engine {
    /// Starts an engine; default: peer listening on `tcp/127.0.0.1:7447`.
    #[new]
    #[pyo3(signature = (*, config=None, mode=None, connect=None, listen=None, name=None))]
    fn new(
        py: Python<'_>,
        config: Option<String>,
        mode: Option<&str>,
        connect: Option<Vec<String>>,
        listen: Option<Vec<String>>,
        name: Option<String>,
    ) -> PyResult<Self> {
        let network = network_options(config, mode, connect, listen, None)?;
        let options = ServerOptions {
            name,
            ..ServerOptions::default()
        };
        let server = py
            .detach(|| EngineServer::open(&network, options))
            .map_err(to_py)?;
        Ok(Self {
            name: server.name().to_owned(),
            server: Mutex::new(Some(server)),
        })
    }

    #[getter]
    fn name(&self) -> &str {
        &self.name
    }

    /// Whether the engine found the default endpoint taken by another engine and joined
    /// it (that engine's clients reach this one through it) instead of listening there.
    #[getter]
    fn joined(&self) -> bool {
        self.lock().as_ref().is_some_and(EngineServer::joined)
    }

    /// Number of sessions it hosts.
    fn session_count(&self) -> usize {
        self.lock().as_ref().map_or(0, EngineServer::session_count)
    }

    /// Stops serving; its sessions are closed.
    fn close(&self, py: Python<'_>) {
        let server = self.lock().take();
        py.detach(move || drop(server));
    }
}

impl Engine {
    fn lock(&self) -> std::sync::MutexGuard<'_, Option<EngineServer>> {
        self.server.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// A Zenoh client with its liveliness token; owns the sessions it makes.
#[pyclass(module = "ciflow._native")]
struct ClientHandle {
    client: Client,
}

#[pymethods]
impl ClientHandle {
    /// Joins Zenoh as a client (default: connect to `tcp/127.0.0.1:7447`) named
    /// `identity` (default `anonymous`; behind a router with access control, the name it
    /// authenticates). Raises `EngineUnreachable` when nothing listens.
    #[staticmethod]
    #[pyo3(signature = (*, config=None, mode=None, connect=None, listen=None, identity=None, timeout=10.0))]
    fn open(
        py: Python<'_>,
        config: Option<String>,
        mode: Option<&str>,
        connect: Option<Vec<String>>,
        listen: Option<Vec<String>>,
        identity: Option<String>,
        timeout: f64,
    ) -> PyResult<Self> {
        let network = network_options(config, mode, connect, listen, identity)?;
        let mut client = py.detach(|| Client::open(&network)).map_err(to_py)?;
        client.set_timeout(seconds(timeout)?);
        Ok(Self { client })
    }

    /// A client sharing the Zenoh session of an engine in this process.
    #[staticmethod]
    #[pyo3(signature = (engine, *, timeout=10.0))]
    fn for_engine(py: Python<'_>, engine: &Engine, timeout: f64) -> PyResult<Self> {
        let session = engine
            .lock()
            .as_ref()
            .map(|server| server.zenoh_session().clone())
            .ok_or_else(|| PyRuntimeError::new_err("the engine is closed"))?;
        let mut client = py.detach(|| Client::with_session(session)).map_err(to_py)?;
        client.set_timeout(seconds(timeout)?);
        Ok(Self { client })
    }

    /// The client's name (its liveliness token is `ciflow/v2/alive/client/<id>`).
    #[getter]
    fn id(&self) -> &str {
        self.client.id()
    }

    /// Reachable engines: `[{"name", "tasks": [{"name", "spec"}], "policies": [...]}]`.
    fn discover<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let engines = py.detach(|| self.client.discover()).map_err(to_py)?;
        engines
            .iter()
            .map(|engine| engine_to_dict(py, engine))
            .collect()
    }

    /// The name of the first reachable engine, in name order, that serves `task` (any
    /// engine for `None`); `None` when no engine does.
    #[pyo3(signature = (task=None))]
    fn first_engine_serving(&self, py: Python<'_>, task: Option<&str>) -> PyResult<Option<String>> {
        py.detach(|| self.client.first_engine_serving(task))
            .map_err(to_py)
    }

    fn engine_info<'py>(&self, py: Python<'py>, engine: &str) -> PyResult<Bound<'py, PyDict>> {
        let info = py
            .detach(|| self.client.engine_info(engine))
            .map_err(to_py)?;
        engine_to_dict(py, &info)
    }

    /// The engines to spread `task` over: `["*"]` for every reachable engine serving it
    /// (name order), else the names given once each, each waited for a moment if it does
    /// not answer yet and checked to serve the task (`spread::resolve_engines`).
    fn resolve_engines(
        &self,
        py: Python<'_>,
        task: &str,
        engines: Vec<String>,
    ) -> PyResult<Vec<String>> {
        py.detach(|| spread::resolve_engines(&self.client, &engines, task))
            .map_err(to_py)
    }

    /// Opens a session of `num_envs` environments of `task` on `engine`, built with the
    /// task's construction arguments `kwargs` (numbers, and strings where the task takes
    /// text).
    #[pyo3(signature = (engine, task, num_envs=1, kwargs=None))]
    fn make(
        &self,
        py: Python<'_>,
        engine: &str,
        task: &str,
        num_envs: u32,
        kwargs: Option<BTreeMap<String, PyKwarg>>,
    ) -> PyResult<Session> {
        let kwargs = kwargs_from_py(kwargs);
        let env = py
            .detach(|| self.client.make(engine, task, num_envs, &kwargs))
            .map_err(to_py)?;
        Ok(Session { env })
    }

    /// The controls of session `session` held by another process, from its `token`;
    /// `engine` names the engine holding it (default: whichever does).
    #[pyo3(signature = (session, token, engine=None))]
    fn attach(&self, session: &str, token: &[u8], engine: Option<&str>) -> PyResult<Control> {
        let engine = engine.unwrap_or(ANY_ENGINE);
        let control = self.client.attach(engine, session, token).map_err(to_py)?;
        Ok(Control { control })
    }

    /// What a session is: `{"task", "kwargs", "num_envs"}`, from the engine, its owner's
    /// identity and its id (as telemetry samples name them); needs no token.
    fn describe<'py>(
        &self,
        py: Python<'py>,
        engine: &str,
        identity: &str,
        session: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let reply = py
            .detach(|| self.client.describe(engine, identity, session))
            .map_err(to_py)?;
        let dict = PyDict::new(py);
        dict.set_item("task", &reply.task)?;
        dict.set_item("kwargs", kwargs_to_dict(py, &reply.kwargs)?)?;
        dict.set_item("num_envs", reply.num_envs)?;
        Ok(dict)
    }

    /// A feed of the telemetry of every session on `engine` (default: every engine) that
    /// this identity may read.
    #[pyo3(signature = (engine=None))]
    fn watch(&self, py: Python<'_>, engine: Option<&str>) -> PyResult<TelemetryFeed> {
        let engine = engine.unwrap_or(ANY_ENGINE);
        let stream = py.detach(|| self.client.watch(engine)).map_err(to_py)?;
        Ok(TelemetryFeed { stream })
    }

    /// A publisher of finished episodes of `task` on
    /// `ciflow/v2/episodes/<task name>/<recorder>`, through this client's Zenoh session.
    fn episode_publisher(
        &self,
        py: Python<'_>,
        task: &str,
        recorder: &str,
    ) -> PyResult<PyEpisodePublisher> {
        let publisher = py
            .detach(|| EpisodePublisher::declare(self.client.zenoh_session(), task, recorder))
            .map_err(to_py)?;
        Ok(PyEpisodePublisher {
            key: publisher.key().to_owned(),
            publisher: Mutex::new(publisher),
        })
    }

    /// Actions of a loaded policy for row-major observations (f64 bytes in and out).
    fn act<'py>(
        &self,
        py: Python<'py>,
        engine: &str,
        policy: &str,
        observations: &[u8],
    ) -> PyResult<Bound<'py, PyByteArray>> {
        let observations = floats_from_bytes("observations", observations)?;
        let actions = py
            .detach(|| self.client.act(engine, policy, &observations))
            .map_err(to_py)?;
        floats_to_bytearray(py, &actions)
    }
}

fn seconds(timeout: f64) -> PyResult<Duration> {
    Duration::try_from_secs_f64(timeout)
        .map_err(|e| PyValueError::new_err(format!("timeout {timeout}: {e}")))
}

fn engine_to_dict<'py>(
    py: Python<'py>,
    engine: &ciflow_bridge::EngineInfo,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("name", &engine.name)?;
    let tasks = engine
        .tasks
        .iter()
        .map(|task| {
            let t = PyDict::new(py);
            t.set_item("name", &task.name)?;
            t.set_item("spec", spec_to_dict(py, &task.spec)?)?;
            Ok(t)
        })
        .collect::<PyResult<Vec<_>>>()?;
    dict.set_item("tasks", tasks)?;
    let policies = engine
        .policies
        .iter()
        .map(|p| {
            let d = PyDict::new(py);
            d.set_item("name", &p.name)?;
            d.set_item("task", &p.task)?;
            d.set_item("observation_dim", p.observation_dim)?;
            d.set_item("action_dim", p.action_dim)?;
            d.set_item("epoch", p.epoch)?;
            d.set_item("validation_nll", p.validation_nll)?;
            Ok(d)
        })
        .collect::<PyResult<Vec<_>>>()?;
    dict.set_item("policies", policies)?;
    Ok(dict)
}

/// Resets every environment of `sessions` as one batch (environment `i` gets seed
/// `seed + i`, or `seeds[i]`), the requests in flight together: `(observations bytes,
/// info columns)`.
#[pyfunction]
#[pyo3(signature = (sessions, seed=None, options=None, seeds=None))]
fn reset_batches<'py>(
    py: Python<'py>,
    sessions: Vec<PyRef<'py, Session>>,
    seed: Option<u64>,
    options: Option<&Bound<'py, PyDict>>,
    seeds: Option<Vec<Option<u64>>>,
) -> PyResult<(Bound<'py, PyByteArray>, Bound<'py, PyDict>)> {
    let options = reset_options_from_dict(options)?;
    let envs: Vec<&RemoteEnv> = sessions.iter().map(|s| &s.env).collect();
    let seeds = BatchSeeds::of_request(seed, seeds)
        .ok_or_else(|| PyValueError::new_err("give seed or seeds, not both"))?;
    let (observations, info) = py
        .detach(|| vector::reset_batches(&envs, seeds, options))
        .map_err(to_py)?;
    Ok((
        floats_to_bytearray(py, &observations)?,
        columns_to_dict(py, &info)?,
    ))
}

/// Steps every environment of `sessions` as one batch with row-major `actions` bytes, the
/// requests in flight together: `(observations, rewards, terminated, truncated, info
/// columns)`, all `bytearray`s (`terminated`/`truncated`: one byte per environment).
#[pyfunction]
#[allow(clippy::type_complexity)]
fn step_batches<'py>(
    py: Python<'py>,
    sessions: Vec<PyRef<'py, Session>>,
    actions: &[u8],
) -> PyResult<(
    Bound<'py, PyByteArray>,
    Bound<'py, PyByteArray>,
    Bound<'py, PyByteArray>,
    Bound<'py, PyByteArray>,
    Bound<'py, PyDict>,
)> {
    let actions = floats_from_bytes("actions", actions)?;
    let envs: Vec<&RemoteEnv> = sessions.iter().map(|s| &s.env).collect();
    let vector::BatchShape {
        envs: count,
        observation_dim,
        ..
    } = vector::batch_shape(&envs).map_err(to_py)?;
    let zeroed = |len| PyByteArray::new_with(py, len, |_| Ok(()));
    let observations = zeroed(8 * count * observation_dim)?;
    let rewards = zeroed(8 * count)?;
    let terminated = zeroed(count)?;
    let truncated = zeroed(count)?;
    // SAFETY: the byte arrays were made just above and nothing else refers to them until
    // they are returned, so no Python code can resize or read them while the GIL is
    // released.
    let out = unsafe {
        BatchStepOut {
            observations: observations.as_bytes_mut(),
            rewards: rewards.as_bytes_mut(),
            terminated: terminated.as_bytes_mut(),
            truncated: truncated.as_bytes_mut(),
        }
    };
    let info = py
        .detach(|| vector::step_batches_into(&envs, &actions, out))
        .map_err(to_py)?;
    Ok((
        observations,
        rewards,
        terminated,
        truncated,
        columns_to_dict(py, &info)?,
    ))
}

/// One session on an engine (1 or `num_envs` environments). Vectors are f64 bytes.
#[pyclass(module = "ciflow._native")]
struct Session {
    env: RemoteEnv,
}

#[pymethods]
impl Session {
    #[getter]
    fn spec<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        spec_to_dict(py, self.env.spec())
    }

    #[getter]
    fn session_id(&self) -> &str {
        self.env.session_id()
    }

    #[getter]
    fn engine(&self) -> &str {
        self.env.engine()
    }

    #[getter]
    fn num_envs(&self) -> u32 {
        self.env.num_envs()
    }

    /// The session's secret (share it to let another process control the session).
    #[getter]
    fn token<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, self.env.token())
    }

    /// `(observation bytes, info)`; `options` is a dict of reset options.
    #[pyo3(signature = (seed=None, options=None))]
    fn reset<'py>(
        &self,
        py: Python<'py>,
        seed: Option<u64>,
        options: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<(Bound<'py, PyBytes>, Bound<'py, PyDict>)> {
        let options = reset_options_from_dict(options)?;
        let (observation, info) = py.detach(|| self.env.reset(seed, options)).map_err(to_py)?;
        Ok((floats_to_bytes(py, &observation), info_dict(py, &info)?))
    }

    /// `(observation bytes, reward, terminated, truncated, info, time)`.
    #[allow(clippy::type_complexity)]
    fn step<'py>(
        &self,
        py: Python<'py>,
        action: &[u8],
    ) -> PyResult<(
        Bound<'py, PyBytes>,
        f64,
        bool,
        bool,
        Bound<'py, PyDict>,
        f64,
    )> {
        let action = floats_from_bytes("action", action)?;
        let step = py.detach(|| self.env.step(&action)).map_err(to_py)?;
        Ok((
            floats_to_bytes(py, &step.observation),
            step.reward,
            step.terminated,
            step.truncated,
            info_dict(py, &step.info)?,
            step.time,
        ))
    }

    #[pyo3(signature = (index=0))]
    fn expert<'py>(&self, py: Python<'py>, index: u32) -> PyResult<Bound<'py, PyBytes>> {
        let action = py.detach(|| self.env.expert(index)).map_err(to_py)?;
        Ok(floats_to_bytes(py, &action))
    }

    /// The session's controls (policy runs, pushes, context changes, telemetry).
    fn control(&self) -> Control {
        Control {
            control: self.env.control().clone(),
        }
    }

    /// RGB bytes, row-major `height × width × 3`.
    #[pyo3(signature = (width, height, index=0))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        width: u32,
        height: u32,
        index: u32,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let pixels = py
            .detach(|| self.env.render(index, width, height))
            .map_err(to_py)?;
        Ok(PyBytes::new(py, &pixels))
    }

    /// Closes the session on the engine (idempotent).
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| self.env.close()).map_err(to_py)
    }
}

/// A session's controls, its owner's or an attached process's (`ciflow.attach`).
#[pyclass(module = "ciflow._native")]
struct Control {
    control: SessionControl,
}

#[pymethods]
impl Control {
    #[getter]
    fn session_id(&self) -> &str {
        self.control.session_id()
    }

    /// The engine's name, or `*` when attached to whichever holds the session.
    #[getter]
    fn engine(&self) -> &str {
        self.control.engine()
    }

    /// Lets `policy` drive environment `index`; returns the simulated time at the start.
    #[pyo3(signature = (policy, speed=1.0, steps=None, index=0))]
    fn run(
        &self,
        py: Python<'_>,
        policy: &str,
        speed: f64,
        steps: Option<u32>,
        index: u32,
    ) -> PyResult<f64> {
        py.detach(|| self.control.run(index, policy, speed, steps))
            .map_err(to_py)
    }

    /// Stops the policy run (no effect without one); returns the simulated time.
    fn stop(&self, py: Python<'_>) -> PyResult<f64> {
        py.detach(|| self.control.stop()).map_err(to_py)
    }

    /// Schedules a perturbation given as a dict (see PROTOCOL.md); returns the time.
    #[pyo3(signature = (perturbation, index=0))]
    fn perturb(
        &self,
        py: Python<'_>,
        perturbation: &Bound<'_, PyDict>,
        index: u32,
    ) -> PyResult<f64> {
        let message = perturbation_from_dict(perturbation)?;
        py.detach(|| self.control.perturb(index, message))
            .map_err(to_py)
    }

    /// Replaces the context (f64 bytes) of environment `index`; returns the time.
    #[pyo3(signature = (context, index=0))]
    fn set_context(&self, py: Python<'_>, context: &[u8], index: u32) -> PyResult<f64> {
        let context = floats_from_bytes("context", context)?;
        py.detach(|| self.control.set_context(index, &context))
            .map_err(to_py)
    }

    /// `None` if environment `index`'s task accepts the context (f64 bytes), else why not.
    #[pyo3(signature = (context, index=0))]
    fn check_context(
        &self,
        py: Python<'_>,
        context: &[u8],
        index: u32,
    ) -> PyResult<Option<String>> {
        let context = floats_from_bytes("context", context)?;
        py.detach(|| self.control.check_context(index, &context))
            .map_err(to_py)
    }

    /// A feed of the session's telemetry samples.
    fn telemetry(&self, py: Python<'_>) -> PyResult<TelemetryFeed> {
        let stream = py.detach(|| self.control.telemetry()).map_err(to_py)?;
        Ok(TelemetryFeed { stream })
    }
}

/// Telemetry samples of one session (or of every watched session), as they arrive.
#[pyclass(module = "ciflow._native")]
struct TelemetryFeed {
    stream: TelemetryStream,
}

/// How long one wait for telemetry lasts before Python may handle a signal (Ctrl-C).
const TELEMETRY_POLL: Duration = Duration::from_millis(200);

#[pymethods]
impl TelemetryFeed {
    /// The next sample as a dict (`state`, `command`, `context` as f64 bytes), or `None`
    /// if none arrives within `timeout` seconds (`None`: wait for one).
    #[pyo3(signature = (timeout=None))]
    fn recv<'py>(
        &self,
        py: Python<'py>,
        timeout: Option<f64>,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let deadline = timeout
            .map(seconds)
            .transpose()?
            .map(|t| Instant::now() + t);
        loop {
            let wait = match deadline {
                Some(deadline) => deadline
                    .saturating_duration_since(Instant::now())
                    .min(TELEMETRY_POLL),
                None => TELEMETRY_POLL,
            };
            if let Some(sourced) = py
                .detach(|| self.stream.recv_sourced(wait))
                .map_err(to_py)?
            {
                let sample = &sourced.telemetry;
                let dict = PyDict::new(py);
                dict.set_item("engine", &sourced.engine)?;
                dict.set_item("identity", &sourced.identity)?;
                dict.set_item("session", &sample.session)?;
                dict.set_item("step", sample.step)?;
                dict.set_item("time", sample.time)?;
                dict.set_item("state", floats_to_bytes(py, &sample.state.0))?;
                dict.set_item("command", floats_to_bytes(py, &sample.command.0))?;
                dict.set_item("context", floats_to_bytes(py, &sample.context.0))?;
                dict.set_item("reward", sample.reward)?;
                dict.set_item("running", sample.running)?;
                dict.set_item("episode_done", sample.episode_done)?;
                dict.set_item("perturbed", sample.perturbed)?;
                return Ok(Some(dict));
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(None);
            }
            py.check_signals()?;
        }
    }
}

fn info_dict<'py>(py: Python<'py>, info: &ciflow_envs::Info) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (key, value) in info {
        dict.set_item(key, *value)?;
    }
    Ok(dict)
}

/// Runs the calling thread, and the threads it starts afterwards, as batch threads
/// (Linux `SCHED_BATCH`, [`ciflow_bridge::scheduling`]): what `python -m ciflow serve`
/// does first, as `ciflow serve` does. `OSError` if the system refuses.
#[pyfunction]
fn run_as_batch() -> PyResult<()> {
    Ok(ciflow_bridge::scheduling::run_as_batch()?)
}

/// `[(gymnasium id, short name)]` of every task this build's engine serves.
#[pyfunction]
fn tasks() -> Vec<(&'static str, &'static str)> {
    ciflow_envs::tasks()
        .iter()
        .map(|t| (t.id, t.name))
        .collect()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(tasks, m)?)?;
    m.add_function(wrap_pyfunction!(run_as_batch, m)?)?;
    m.add_class::<Engine>()?;
    m.add_class::<ClientHandle>()?;
    m.add_class::<Session>()?;
    m.add_function(wrap_pyfunction!(reset_batches, m)?)?;
    m.add_function(wrap_pyfunction!(step_batches, m)?)?;
    m.add_class::<Control>()?;
    m.add_class::<TelemetryFeed>()?;
    m.add_class::<scenes::Scenery>()?;
    m.add_class::<scenes::FlowField>()?;
    m.add_class::<PyDatasetSpec>()?;
    m.add_class::<PyEpisode>()?;
    m.add_class::<PyDatasetWriter>()?;
    m.add_class::<PyEpisodePublisher>()?;
    m.add_function(wrap_pyfunction!(datasets::read_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(datasets::record_expert, m)?)?;
    m.add_function(wrap_pyfunction!(datasets::task_value, m)?)?;
    m.add_function(wrap_pyfunction!(datasets::check_replaceable, m)?)?;
    m.add_function(wrap_pyfunction!(datasets::check_options_keep_kwargs, m)?)?;
    m.add_function(wrap_pyfunction!(datasets::task_argument, m)?)?;
    m.add("CiflowError", m.py().get_type::<CiflowError>())?;
    m.add("EngineUnreachable", m.py().get_type::<EngineUnreachable>())?;
    m.add("DEFAULT_ENDPOINT", ciflow_bridge::DEFAULT_ENDPOINT)?;
    m.add(
        "PROTOCOL_VERSION",
        ciflow_bridge::protocol::PROTOCOL_VERSION,
    )?;
    Ok(())
}
