//! The environment shared by the arm tasks: a serial arm driven through the
//! computed-torque layer, whose task supplies context, start posture, expert, reward and
//! scene.
//!
//! State `(q, q̇) ∈ Rⁿ × Rⁿ`, action `a = q̈_des` within the arm's acceleration limits,
//! observation `[q, q̇, c]` (positions within the joint limits, velocities unbounded: a
//! push can exceed the nominal speed limits). The arm runs under the engine's
//! [`Simulator`] with 1 ms physics and 10 ms control, so pushes act through the real
//! dynamics: `q̈ = q̈_des + M⁻¹ τ_ext`. The reset option
//! [`PUSH_FORCE_OPTION`](arm_start::PUSH_FORCE_OPTION) pushes the last link once per
//! episode ([`arm_start::demo_push`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use ciflow_engine::math::{DVector, Vector3};
use ciflow_engine::robot::{DynamicsError, Robot};
use ciflow_engine::sim::{Perturbation, SimConfig, Simulator};
use rand_chacha::ChaCha8Rng;

use crate::env::{
    Env, EnvError, EnvSpec, Info, Outcome, PERTURBED_INFO, Phase, ResetOptions, StepOutcome,
};
use crate::scene::{self, Body, Scene};
use crate::shading::{self, Camera, Picture};
use crate::simulated::SimulatedEpisode;
use crate::space::{BoxSpace, Dtype};
use crate::tasks::arm_start;

/// Physics and control periods of every arm task, s.
const PHYSICS_DT: f64 = 0.001;
const CONTROL_DT: f64 = 0.01;

/// Fixed facts about an arm task.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmSetup {
    /// Gymnasium id.
    pub id: &'static str,
    pub max_episode_steps: u32,
    /// The name `render` gives the trail of the traced point (the scene's body name).
    pub trail: &'static str,
}

/// An arm task: the parts of an environment that differ between tasks.
pub trait ArmTask: Send + 'static {
    /// What the task reads of the arm's posture at each step (the cup, the tool): worked
    /// out once per step for the trail and the outcome.
    type Pose;

    fn setup(&self) -> &ArmSetup;
    fn context_space(&self) -> &BoxSpace;
    /// Applies the task's reset options (`ResetOptions::extra`).
    /// [`PUSH_FORCE_OPTION`](arm_start::PUSH_FORCE_OPTION) is the environment's; any other
    /// key the task does not know is an error.
    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError>;
    /// The context of an episode, drawn from `rng`.
    fn sample_context(&self, robot: &dyn Robot, rng: &mut ChaCha8Rng)
    -> Result<Vec<f64>, EnvError>;
    /// A start posture, drawn from `rng` after the context.
    fn sample_start(&self, robot: &dyn Robot, rng: &mut ChaCha8Rng) -> Vec<f64>;
    /// Makes `context` current; it lies in the context space.
    fn set_context(&mut self, context: &[f64]);
    fn pose(&self, robot: &dyn Robot, q: &[f64]) -> Result<Self::Pose, EnvError>;
    /// The point of `pose` whose trail `render` draws.
    fn traced_point(pose: &Self::Pose) -> Vector3;
    /// Reward and termination at `pose`; the task's own info values go into `info` (the
    /// environment adds [`PERTURBED_INFO`] and `time`).
    fn evaluate(&self, pose: &Self::Pose, info: &mut Info) -> Outcome;
    /// The expert's `q̈_des` at `(q, q̇)` for the current context, before clipping.
    fn expert_acceleration(
        &self,
        robot: &dyn Robot,
        q: &[f64],
        qd: &[f64],
    ) -> Result<DVector, DynamicsError>;
    /// The bodies of the scene with the arm at `q` and the context `context`.
    fn bodies(&self, robot: &dyn Robot, q: &[f64], context: &[f64]) -> Result<Vec<Body>, EnvError>;
    /// The camera of `render`.
    fn camera(&self) -> Camera;
}

/// An arm task as an [`Env`].
pub struct ArmEnv<T: ArmTask> {
    task: T,
    spec: Arc<EnvSpec>,
    /// The arm's episode; its trail holds the traced point's positions.
    episode: SimulatedEpisode<Vector3>,
}

impl<T: ArmTask> ArmEnv<T> {
    /// The task on `robot`, at rest at `q = 0` (clamped into the limits) until reset.
    pub fn with_robot(task: T, robot: Box<dyn Robot>) -> Result<Self, EnvError> {
        let limits = robot.limits().clone();
        let n = robot.dof();
        let config = SimConfig {
            physics_dt: PHYSICS_DT,
            control_dt: CONTROL_DT,
            ..SimConfig::default()
        };
        let context_space = task.context_space().clone();
        let observation_space = BoxSpace::new(
            [
                limits.q_min.as_slice(),
                &vec![f64::NEG_INFINITY; n],
                &context_space.low,
            ]
            .concat(),
            [
                limits.q_max.as_slice(),
                &vec![f64::INFINITY; n],
                &context_space.high,
            ]
            .concat(),
            Dtype::Float64,
        );
        let spec = EnvSpec {
            id: task.setup().id.into(),
            observation_space,
            action_space: BoxSpace::new(
                (-&limits.qdd_max).as_slice().to_vec(),
                limits.qdd_max.as_slice().to_vec(),
                Dtype::Float64,
            ),
            context_space,
            control_dt: config.control_dt,
            physics_dt: config.physics_dt,
            max_episode_steps: task.setup().max_episode_steps,
        }
        .shared();
        let simulator = Simulator::new(robot, config).map_err(EnvError::Simulation)?;
        Ok(Self {
            task,
            spec,
            episode: SimulatedEpisode::new(simulator),
        })
    }

    pub fn task(&self) -> &T {
        &self.task
    }

    pub fn robot(&self) -> &dyn Robot {
        self.episode.simulator.robot()
    }

    /// The task's pose of the arm now.
    pub fn pose(&self) -> Result<T::Pose, EnvError> {
        self.task
            .pose(self.robot(), self.episode.simulator.q().as_slice())
    }

    /// Reward and termination at `pose`; `info` replaced by the task's values,
    /// [`PERTURBED_INFO`] and `time`.
    fn outcome(&self, pose: &T::Pose, info: &mut Info) -> Outcome {
        info.clear();
        let outcome = self.task.evaluate(pose, info);
        let simulator = &self.episode.simulator;
        let perturbed = f64::from(u8::from(simulator.perturbed()));
        info.insert(PERTURBED_INFO.into(), perturbed);
        info.insert("time".into(), simulator.time());
        outcome
    }

    fn apply_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.spec.context_space.check("context", context)?;
        self.task.set_context(context);
        self.episode.context = context.to_vec();
        Ok(())
    }

    /// The shaded picture `render` returns, with which body each pixel shows: the
    /// [`Env::scene`] of the current observation and the traced point's trail (unless
    /// [`Env::record_trail`] turned it off), seen by the task's camera (blank before the
    /// first reset).
    pub fn picture(&self, width: u32, height: u32) -> Result<Picture, EnvError> {
        let mut scene = Scene::default();
        if self.episode.phase != Phase::NeedsReset {
            scene = self.scene(&self.episode.observation())?;
            let trail = self.episode.trail();
            if !trail.is_empty() {
                scene
                    .bodies
                    .push(scene::trail(self.task.setup().trail, trail));
            }
        }
        shading::render(&scene, &self.task.camera(), width, height)
    }
}

impl<T: ArmTask> Env for ArmEnv<T> {
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
        let push_force = arm_start::push_force(&options.extra)?;
        let robot = self.episode.simulator.robot();
        let rng = self.episode.rng.reseed(seed);
        let context = match &options.context {
            Some(context) => context.clone(),
            None => self.task.sample_context(robot, rng)?,
        };
        let q0 = match &options.initial_position {
            Some(q0) => arm_start::initial_position(q0, robot.limits())?,
            None => self.task.sample_start(robot, rng),
        };
        let joints = robot.dof();
        let qd0 = match &options.initial_velocity {
            Some(qd0) => arm_start::joint_vector("initial_velocity", qd0, joints)?,
            None => vec![0.0; joints],
        };
        // Drawn after the start, so a pushed episode starts where the unpushed one does.
        let push = arm_start::demo_push(self.episode.rng.reseed(None), push_force, joints - 1);
        self.apply_context(&context)?;
        let simulator = &mut self.episode.simulator;
        simulator.reset(&q0, &qd0).map_err(EnvError::Simulation)?;
        if let Some(push) = push {
            simulator
                .perturb(push)
                .map_err(EnvError::InvalidPerturbation)?;
        }
        let pose = self.pose()?;
        self.episode
            .start(T::traced_point(&pose), self.spec.max_episode_steps);
        let mut info = Info::new();
        self.outcome(&pose, &mut info);
        Ok((self.episode.observation(), info))
    }

    fn step_into(
        &mut self,
        action: &[f64],
        observation: &mut [f64],
        info: &mut Info,
    ) -> Result<StepOutcome, EnvError> {
        self.episode.advance(&self.spec, action, observation)?;
        let pose = self.pose()?;
        let outcome = self.outcome(&pose, info);
        Ok(self.episode.finish_step(
            T::traced_point(&pose),
            outcome,
            self.spec.max_episode_steps,
            observation,
        ))
    }

    fn expert_action(&self) -> Result<Vec<f64>, EnvError> {
        self.episode.phase.started()?;
        let simulator = &self.episode.simulator;
        let qdd = self
            .task
            .expert_acceleration(
                self.robot(),
                simulator.q().as_slice(),
                simulator.qd().as_slice(),
            )
            .map_err(|e| EnvError::Simulation(e.into()))?;
        Ok(self.spec.action_space.clip(qdd.as_slice()))
    }

    fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.episode.phase.started()?;
        self.apply_context(context)
    }

    fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
        self.episode.perturb(perturbation)
    }

    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError> {
        Ok(self.picture(width, height)?.into_pixels())
    }

    fn record_trail(&mut self, recording: bool) {
        self.episode.record_trail(recording);
    }

    fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError> {
        let (state, context) = self.spec.split_observation(observation)?;
        let q = &state[..self.robot().dof()];
        let bodies = self.task.bodies(self.robot(), q, context)?;
        Ok(Scene { bodies })
    }
}
