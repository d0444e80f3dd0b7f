//! The environment shared by the planar tasks: a point mass driven through the
//! computed-torque layer, whose task supplies context, start state, expert field, reward
//! and scene.
//!
//! State `(x, ẋ) ∈ R² × R²`, action `a = ẍ_des`, observation `[x, ẋ, c]`. The robot is
//! the engine's [`PointMass2d`] (1 kg) under [`Simulator`], so perturbation forces act
//! through the real dynamics: `ẍ = a + f_ext / m`.

use std::collections::BTreeMap;
use std::sync::Arc;

use ciflow_engine::robot::PointMass2d;
use ciflow_engine::sim::{Perturbation, SimConfig, Simulator};
use nalgebra::Vector2;
use rand_chacha::ChaCha8Rng;

use crate::env::{Env, EnvError, EnvSpec, Info, Outcome, Phase, ResetOptions, StepOutcome};
use crate::expert::tracking::{VelocityField, tracking_acceleration};
use crate::raster::{BLACK, BLUE, Canvas, View};
use crate::scene::{Body, Scene, Shape, planar};
use crate::simulated::SimulatedEpisode;
use crate::space::{BoxSpace, Dtype};

/// Mass of the point, kg.
pub const MASS: f64 = 1.0;

/// Fixed facts about a planar task.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanarSetup {
    /// Gymnasium id.
    pub id: &'static str,
    /// The region shown by `render` and from which starts are drawn.
    pub workspace: View,
    /// Bound of each action component, m/s² (or the task's length unit per s²).
    pub max_acceleration: f64,
    pub control_dt: f64,
    pub physics_dt: f64,
    pub max_episode_steps: u32,
}

/// A planar task: the parts of an environment that differ between tasks.
pub trait PlanarTask: Send + 'static {
    fn setup(&self) -> &PlanarSetup;
    fn context_space(&self) -> &BoxSpace;
    /// Applies task-specific reset options (`ResetOptions::extra`); unknown keys are errors.
    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError>;
    /// The context of an episode reset with `seed` (`None`: an unseeded reset), drawn
    /// from `rng`, or scheduled by episode where the task demonstrates a fixed set.
    fn sample_context(&mut self, seed: Option<u64>, rng: &mut ChaCha8Rng) -> Vec<f64>;
    /// Checks a context beyond its space (e.g. obstacles that overlap the target).
    fn check_context(&self, _context: &[f64]) -> Result<(), EnvError> {
        Ok(())
    }
    /// Makes `context` current (rebuilds the expert); it has passed the checks.
    fn set_context(&mut self, context: &[f64]);
    /// A start position for the current context.
    fn sample_start(&self, rng: &mut ChaCha8Rng) -> Vector2<f64>;
    /// Checks a start position given in the reset options.
    fn check_start(&self, _x: &Vector2<f64>) -> Result<(), EnvError> {
        Ok(())
    }
    /// The expert's first-order system for the current context.
    fn field(&self) -> &dyn VelocityField;
    /// `k_v` of the expert's [`tracking_acceleration`], 1/s.
    fn velocity_gain(&self) -> f64;
    /// Reward and termination at `(x, ẋ)`; the task's own info values go into `info` (the
    /// environment adds `time`).
    fn evaluate(&self, x: &Vector2<f64>, xd: &Vector2<f64>, info: &mut Info) -> Outcome;
    /// Draws the task's scene (targets, obstacles, outlines) under the trajectory.
    fn draw(&self, canvas: &mut Canvas);
    /// The context's objects (targets, obstacles, outlines) in the plane `z = 0`.
    fn context_bodies(&self, context: &[f64]) -> Vec<Body>;
}

/// A planar task as an [`Env`].
pub struct PlanarEnv<T: PlanarTask> {
    task: T,
    spec: Arc<EnvSpec>,
    /// The point mass's episode; its trail holds the positions visited.
    episode: SimulatedEpisode<Vector2<f64>>,
}

impl<T: PlanarTask> PlanarEnv<T> {
    pub fn new(task: T) -> Result<Self, EnvError> {
        let setup = task.setup().clone();
        let config = SimConfig {
            physics_dt: setup.physics_dt,
            control_dt: setup.control_dt,
            ..SimConfig::default()
        };
        let robot = PointMass2d::new(MASS).map_err(|e| EnvError::Simulation(e.into()))?;
        let simulator = Simulator::new(Box::new(robot), config).map_err(EnvError::Simulation)?;
        let context_space = task.context_space().clone();
        let unbounded = |n: usize| vec![f64::INFINITY; n];
        let observation_space = BoxSpace::new(
            [vec![f64::NEG_INFINITY; 4], context_space.low.clone()].concat(),
            [unbounded(4), context_space.high.clone()].concat(),
            Dtype::Float64,
        );
        let a = setup.max_acceleration;
        let spec = EnvSpec {
            id: setup.id.to_string(),
            observation_space,
            action_space: BoxSpace::new(vec![-a; 2], vec![a; 2], Dtype::Float64),
            context_space,
            control_dt: setup.control_dt,
            physics_dt: setup.physics_dt,
            max_episode_steps: setup.max_episode_steps,
        }
        .shared();
        Ok(Self {
            task,
            spec,
            episode: SimulatedEpisode::new(simulator),
        })
    }

    pub fn task(&self) -> &T {
        &self.task
    }

    /// Position `x` and velocity `ẋ` now.
    pub fn state(&self) -> (Vector2<f64>, Vector2<f64>) {
        let simulator = &self.episode.simulator;
        let (q, qd) = (simulator.q(), simulator.qd());
        (Vector2::new(q[0], q[1]), Vector2::new(qd[0], qd[1]))
    }

    /// The point's drawn radius: a fixed share of the workspace's diagonal.
    fn point_radius(&self) -> f64 {
        0.012 * (self.task.setup().workspace.max - self.task.setup().workspace.min).norm()
    }

    /// Reward and termination now; `info` replaced by the task's values and `time`.
    fn outcome(&self, info: &mut Info) -> Outcome {
        let (x, xd) = self.state();
        info.clear();
        let outcome = self.task.evaluate(&x, &xd, info);
        info.insert("time".into(), self.episode.simulator.time());
        outcome
    }
}

fn vector2(what: &'static str, values: &[f64]) -> Result<Vector2<f64>, EnvError> {
    match values {
        [x, y] if x.is_finite() && y.is_finite() => Ok(Vector2::new(*x, *y)),
        [_, _] => Err(EnvError::NotFinite { what }),
        _ => Err(EnvError::WrongDimension {
            what,
            expected: 2,
            got: values.len(),
        }),
    }
}

impl<T: PlanarTask> Env for PlanarEnv<T> {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(
        &mut self,
        seed: Option<u64>,
        options: &ResetOptions,
    ) -> Result<(Vec<f64>, Info), EnvError> {
        // A failed reset leaves no episode to step: the task may be half reconfigured.
        self.episode.phase = Phase::NeedsReset;
        self.task.configure(&options.extra)?;
        let rng = self.episode.rng.reseed(seed);
        let context = match &options.context {
            Some(context) => context.clone(),
            None => self.task.sample_context(seed, rng),
        };
        self.check_context(&context)?;
        self.task.set_context(&context);
        let x0 = match &options.initial_position {
            Some(x0) => {
                let x0 = vector2("initial_position", x0)?;
                self.task.check_start(&x0)?;
                x0
            }
            None => self.task.sample_start(self.episode.rng.reseed(None)),
        };
        let xd0 = match &options.initial_velocity {
            Some(xd0) => vector2("initial_velocity", xd0)?,
            None => Vector2::zeros(),
        };
        self.episode
            .simulator
            .reset(x0.as_slice(), xd0.as_slice())
            .map_err(EnvError::Simulation)?;
        self.episode.context = context;
        self.episode.start(x0, self.spec.max_episode_steps);
        let mut info = Info::new();
        self.outcome(&mut info);
        Ok((self.episode.observation(), info))
    }

    fn step_into(
        &mut self,
        action: &[f64],
        observation: &mut [f64],
        info: &mut Info,
    ) -> Result<StepOutcome, EnvError> {
        self.episode.advance(&self.spec, action, observation)?;
        let outcome = self.outcome(info);
        let point = self.state().0;
        Ok(self
            .episode
            .finish_step(point, outcome, self.spec.max_episode_steps, observation))
    }

    fn expert_action(&self) -> Result<Vec<f64>, EnvError> {
        self.episode.phase.started()?;
        let (x, xd) = self.state();
        let a = tracking_acceleration(self.task.field(), &x, &xd, self.task.velocity_gain());
        Ok(self.spec.action_space.clip(a.as_slice()))
    }

    fn check_context(&self, context: &[f64]) -> Result<(), EnvError> {
        self.spec.context_space.check("context", context)?;
        self.task.check_context(context)
    }

    fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.episode.phase.started()?;
        self.check_context(context)?;
        self.task.set_context(context);
        self.episode.context = context.to_vec();
        Ok(())
    }

    fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
        self.episode.perturb(perturbation)
    }

    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError> {
        let mut canvas = Canvas::new(width, height, self.task.setup().workspace)?;
        if self.episode.phase != Phase::NeedsReset {
            self.task.draw(&mut canvas);
            canvas.polyline(self.episode.trail(), false, BLUE, 2.0);
            canvas.disc(&self.state().0, self.point_radius(), BLACK);
        }
        Ok(canvas.into_pixels())
    }

    fn record_trail(&mut self, recording: bool) {
        self.episode.record_trail(recording);
    }

    /// The point mass as a ball on the plane `z = 0`, and the task's context bodies.
    fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError> {
        let (state, context) = self.spec.split_observation(observation)?;
        let centre = planar(&Vector2::new(state[0], state[1]));
        let point = Body::new("point", Shape::sphere(centre, self.point_radius()), BLACK);
        let mut bodies = self.task.context_bodies(context);
        bodies.push(point);
        Ok(Scene { bodies })
    }
}

/// Rejects option (or construction argument) keys a task does not know.
pub fn reject_unknown_options<V>(
    extra: &BTreeMap<String, V>,
    known: &[&str],
) -> Result<(), EnvError> {
    match extra.keys().find(|k| !known.contains(&k.as_str())) {
        Some(key) => Err(EnvError::InvalidOption {
            name: key.clone(),
            detail: if known.is_empty() {
                "this task takes none".into()
            } else {
                format!("not an option of this task (known: {})", known.join(", "))
            },
        }),
        None => Ok(()),
    }
}

/// The option `name` as an index below `count`, if given.
pub fn index_option(
    options: &BTreeMap<String, f64>,
    name: &str,
    count: usize,
) -> Result<Option<usize>, EnvError> {
    match options.get(name) {
        None => Ok(None),
        Some(&v) if v.fract() == 0.0 && (0.0..count as f64).contains(&v) => Ok(Some(v as usize)),
        Some(v) => Err(EnvError::InvalidOption {
            name: name.into(),
            detail: format!("{v} is not a whole number in [0, {count})"),
        }),
    }
}
