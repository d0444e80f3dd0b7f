//! What viewers (`ciflow.view`) draw: `Scenery`, a task's 3-D bodies at any observation,
//! and `FlowField`, a 2-D flow policy's field and latent-grid deformation per context.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Mutex;

use ciflow_bridge::error::full_message;
use ciflow_engine::flow::Policy;
use ciflow_engine::robot::Robot;
use ciflow_envs::scene::{Body, Shape, axis_pose};
use ciflow_envs::{Env, EnvError};
use ciflow_evaluation::field::{FieldConfig, field};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{PyKwarg, kwargs_from_py};

/// The bodies of `task` built with `kwargs` at any of its observations: the robot, the
/// context's objects. Holds one environment of the task, never reset or stepped, and the
/// arm it drives (for tasks with one).
#[pyclass(module = "ciflow._native")]
pub struct Scenery {
    env: Mutex<Box<dyn Env>>,
    robot: Option<Box<dyn Robot>>,
}

#[pymethods]
impl Scenery {
    #[new]
    #[pyo3(signature = (task, kwargs=None))]
    fn new(task: &str, kwargs: Option<BTreeMap<String, PyKwarg>>) -> PyResult<Self> {
        let kwargs = kwargs_from_py(kwargs);
        let refused = |e: EnvError| PyValueError::new_err(full_message(&e));
        let entry = ciflow_envs::registry::entry(task).map_err(refused)?;
        let env = (entry.make_with)(&kwargs).map_err(refused)?;
        let robot = entry
            .robot
            .map(|make| make(&kwargs))
            .transpose()
            .map_err(refused)?;
        Ok(Self {
            env: Mutex::new(env),
            robot,
        })
    }

    /// The placement of every named frame of the task's arm (its URDF links, base and
    /// tool) at `observation`, whose first entries are the joint positions: `{name:
    /// (translation, quaternion xyzw)}`; empty for tasks without an arm.
    fn frame_placements<'py>(
        &self,
        py: Python<'py>,
        observation: Vec<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let placements = PyDict::new(py);
        let Some(robot) = &self.robot else {
            return Ok(placements);
        };
        let q = observation.get(..robot.dof()).ok_or_else(|| {
            PyValueError::new_err(format!(
                "an observation of {} values holds no {} joint positions",
                observation.len(),
                robot.dof()
            ))
        })?;
        for (index, frame) in robot.frames().iter().enumerate() {
            let placement = robot
                .frame_placement(q, index)
                .map_err(|e| PyValueError::new_err(full_message(&e)))?;
            let t = placement.translation.vector;
            let r = placement.rotation.coords;
            placements.set_item(&frame.name, ([t.x, t.y, t.z], [r.x, r.y, r.z, r.w]))?;
        }
        Ok(placements)
    }

    /// The bodies at `observation` (state then context): a list of dicts with `name`,
    /// `color` (RGB 0–255), `kind` and the shape's fields — `capsule`: `from`, `to`,
    /// `radius`, and the same as `translation` (at `from`), `quaternion` (its `z` toward
    /// `to`) and `length`; `cylinder`: `translation` (base centre), `quaternion` (xyzw; the axis is
    /// its `z`), `radius`, `height`; `cuboid`: `translation` (centre), `quaternion`,
    /// `half_extents`; `sphere`: `centre`, `radius`; `curve`: `points`, `closed`, `radius`.
    fn scene<'py>(
        &self,
        py: Python<'py>,
        observation: Vec<f64>,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let scene = self
            .env
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .scene(&observation)
            .map_err(|e| PyValueError::new_err(full_message(&e)))?;
        scene.bodies.iter().map(|b| body_to_dict(py, b)).collect()
    }
}

/// A 2-D flow policy loaded from its checkpoint directory, whose figure data — the
/// learned vector field, noise-free rollouts and the image of the latent grid — viewers
/// draw for the context a session is in (the same data as `ciflow evaluate --field`).
#[pyclass(module = "ciflow._native")]
pub struct FlowField {
    policy: Mutex<Policy>,
}

#[pymethods]
impl FlowField {
    #[new]
    fn new(py: Python<'_>, checkpoint: PathBuf) -> PyResult<Self> {
        let policy = py
            .detach(|| Policy::load(&checkpoint, None))
            .map_err(|e| PyValueError::new_err(full_message(&e)))?;
        Ok(Self {
            policy: Mutex::new(policy),
        })
    }

    /// The policy's task (Gymnasium id).
    #[getter]
    fn task(&self) -> String {
        self.lock().config().task.clone()
    }

    /// The figure data for `context` as JSON: `{task, window, fields: [{context, x, y,
    /// velocity_x, velocity_y, rollouts, latent_grid, reference?}]}`, on a
    /// `resolution`² grid over `window` (`[x_min, x_max, y_min, y_max]`; default: the
    /// training data's box widened by a quarter) with `latent_lines` lines per latent axis.
    #[pyo3(signature = (context, window=None, resolution=20, latent_lines=10, rollout_steps=400))]
    fn at(
        &self,
        py: Python<'_>,
        context: Vec<f64>,
        window: Option<[f64; 4]>,
        resolution: usize,
        latent_lines: usize,
        rollout_steps: usize,
    ) -> PyResult<String> {
        let config = FieldConfig {
            contexts: vec![context],
            window,
            resolution,
            starts: None,
            rollout_steps,
            latent_lines,
        };
        let report = py
            .detach(|| field(&self.lock(), &config, &[]))
            .map_err(|e| PyValueError::new_err(full_message(&e)))?;
        serde_json::to_string(&report).map_err(|e| PyValueError::new_err(e.to_string()))
    }
}

impl FlowField {
    fn lock(&self) -> std::sync::MutexGuard<'_, Policy> {
        self.policy.lock().unwrap_or_else(|p| p.into_inner())
    }
}

fn body_to_dict<'py>(py: Python<'py>, body: &Body) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("name", &body.name)?;
    let [r, g, b] = body.color;
    dict.set_item("color", (r, g, b))?;
    let xyz = |v: &nalgebra::Vector3<f64>| [v.x, v.y, v.z];
    let pose = |pose: &nalgebra::Isometry3<f64>| -> PyResult<()> {
        let q = pose.rotation.coords;
        dict.set_item("translation", xyz(&pose.translation.vector))?;
        dict.set_item("quaternion", [q.x, q.y, q.z, q.w])
    };
    match &body.shape {
        Shape::Capsule { from, to, radius } => {
            dict.set_item("kind", "capsule")?;
            dict.set_item("from", xyz(from))?;
            dict.set_item("to", xyz(to))?;
            dict.set_item("radius", radius)?;
            let (placement, length) = axis_pose(from, to);
            pose(&placement)?;
            dict.set_item("length", length)?;
        }
        Shape::Cylinder {
            pose: placement,
            radius,
            height,
        } => {
            dict.set_item("kind", "cylinder")?;
            pose(placement)?;
            dict.set_item("radius", radius)?;
            dict.set_item("height", height)?;
        }
        Shape::Cuboid {
            pose: placement,
            half_extents,
        } => {
            dict.set_item("kind", "cuboid")?;
            pose(placement)?;
            dict.set_item("half_extents", xyz(half_extents))?;
        }
        Shape::Sphere { centre, radius } => {
            dict.set_item("kind", "sphere")?;
            dict.set_item("centre", xyz(centre))?;
            dict.set_item("radius", radius)?;
        }
        Shape::Curve {
            points,
            closed,
            radius,
        } => {
            dict.set_item("kind", "curve")?;
            dict.set_item("points", points.iter().map(xyz).collect::<Vec<_>>())?;
            dict.set_item("closed", closed)?;
            dict.set_item("radius", radius)?;
        }
    }
    Ok(dict)
}
