//! The environment interface shared by every task, the bridge and the Python client.

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::{Arc, Mutex, PoisonError, Weak};

use ciflow_engine::sim::Perturbation;
use serde::{Deserialize, Serialize};

use crate::scene::Scene;
use crate::space::BoxSpace;

pub use crate::error::EnvError;
pub use crate::info::Info;

/// Info key, 0/1: the task is achieved (Gymnasium's convention; each task documents when).
pub const SUCCESS_INFO: &str = "is_success";

/// Info key, 0/1: an external force moved the robot during the step. Such a step shows the
/// disturbance, not the controller: trainers leave it (and optionally a settling window
/// after it) out of the likelihood.
pub const PERTURBED_INFO: &str = "perturbed";

/// What a task is: its id, spaces and timing. Everything a client needs before `reset`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvSpec {
    /// Gymnasium id, e.g. `ciflow/Pouring-v0`.
    pub id: String,
    pub observation_space: BoxSpace,
    /// Desired joint accelerations `q̈_des` in rad/s² (or m/s² for point masses).
    pub action_space: BoxSpace,
    /// The context `c` (also the tail of every observation).
    pub context_space: BoxSpace,
    /// Seconds of simulated time per `step` (the control period).
    pub control_dt: f64,
    /// Seconds per physics substep.
    pub physics_dt: f64,
    /// Episode length after which `truncated` is set.
    pub max_episode_steps: u32,
}

impl EnvSpec {
    /// The number of generalized positions `q`: an observation's state is `[q, q̇]`.
    pub fn position_dim(&self) -> usize {
        (self.observation_space.dim() - self.context_space.dim()) / 2
    }

    /// Splits an observation into its state and its context, refusing a wrong length or a
    /// non-finite entry (values outside the observation space pass: viewers draw pushed
    /// or extrapolated states as they are).
    pub fn split_observation<'a>(
        &self,
        observation: &'a [f64],
    ) -> Result<(&'a [f64], &'a [f64]), EnvError> {
        self.observation_space
            .check_dim("observation", observation)?;
        if observation.iter().any(|v| !v.is_finite()) {
            return Err(EnvError::NotFinite {
                what: "observation",
            });
        }
        Ok(observation.split_at(observation.len() - self.context_space.dim()))
    }

    /// Refuses a buffer for [`Env::step_into`] whose length is not the observation's.
    pub fn check_observation_buffer(&self, buffer: &[f64]) -> Result<(), EnvError> {
        self.observation_space
            .check_dim("observation buffer", buffer)
    }

    /// This spec, shared with every living environment whose spec equals it: the
    /// thousands of environments of a batched session then check their actions against
    /// one copy of the bounds, which stays in cache, instead of one copy each.
    pub fn shared(self) -> Arc<EnvSpec> {
        static SPECS: Mutex<Vec<Weak<EnvSpec>>> = Mutex::new(Vec::new());
        let mut specs = SPECS.lock().unwrap_or_else(PoisonError::into_inner);
        specs.retain(|spec| spec.strong_count() > 0);
        if let Some(spec) = specs.iter().filter_map(Weak::upgrade).find(|s| **s == self) {
            return spec;
        }
        let spec = Arc::new(self);
        specs.push(Arc::downgrade(&spec));
        spec
    }
}

/// Options accepted by [`Env::reset`]; unset fields are drawn from the task's documented
/// distributions with the environment's RNG.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ResetOptions {
    /// The context `c`; must lie in the context space.
    pub context: Option<Vec<f64>>,
    /// Initial generalized positions.
    pub initial_position: Option<Vec<f64>>,
    /// Initial generalized velocities (zero when unset).
    pub initial_velocity: Option<Vec<f64>>,
    /// Task-specific integer or real options, e.g. `obstacles` or `shape`.
    #[serde(default)]
    pub extra: BTreeMap<String, f64>,
}

impl ResetOptions {
    /// The options of environments `envs` of a batch of `n` made alike (`spec`), as a
    /// vector environment's reset gives them: each of `context`, `initial_position` and
    /// `initial_velocity` holds one value for every environment (`d` numbers) or one row
    /// per environment (`n · d` numbers, row `i` for environment `i`), of which the rows of
    /// `envs` are kept — one value when `envs` holds one environment. A field of any other
    /// length is kept as it is ([`check_rows`](Self::check_rows) refuses it).
    pub fn rows(&self, n: usize, envs: Range<usize>, spec: &EnvSpec) -> ResetOptions {
        let [context, initial_position, initial_velocity] =
            self.row_fields(spec).map(|(_, field, d)| {
                field.as_ref().map(|values| {
                    if is_rows(values, n, d) {
                        values[envs.start * d..envs.end * d].to_vec()
                    } else {
                        values.clone()
                    }
                })
            });
        ResetOptions {
            context,
            initial_position,
            initial_velocity,
            extra: self.extra.clone(),
        }
    }

    /// Whether a field holds one row per environment of a batch of `n` (see
    /// [`rows`](Self::rows)).
    pub fn has_rows(&self, n: usize, spec: &EnvSpec) -> bool {
        self.row_fields(spec)
            .into_iter()
            .any(|(_, field, d)| field.as_ref().is_some_and(|values| is_rows(values, n, d)))
    }

    /// Checks that every field holds one value for all `n` environments of a batch or one
    /// row for each: a length that is neither would reach each environment whole, which
    /// could only refuse it as a value of the wrong size.
    pub fn check_rows(&self, n: usize, spec: &EnvSpec) -> Result<(), EnvError> {
        for (what, field, per_env) in self.row_fields(spec) {
            if let Some(values) = field
                && n > 1
                && values.len() != per_env
                && !is_rows(values, n, per_env)
            {
                return Err(EnvError::BatchDimension {
                    what,
                    per_env,
                    envs: n,
                    got: values.len(),
                });
            }
        }
        Ok(())
    }

    /// The fields that may hold one row per environment, with their names and the
    /// dimension of one row under `spec`.
    fn row_fields(&self, spec: &EnvSpec) -> [(&'static str, &Option<Vec<f64>>, usize); 3] {
        let (positions, context) = (spec.position_dim(), spec.context_space.dim());
        [
            ("context", &self.context, context),
            ("initial_position", &self.initial_position, positions),
            ("initial_velocity", &self.initial_velocity, positions),
        ]
    }
}

/// `values` are `n > 1` rows of `d > 0` numbers.
fn is_rows(values: &[f64], n: usize, d: usize) -> bool {
    n > 1 && d > 0 && values.len() == n * d
}

/// Where an environment is in its episode, and the checks its methods share.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Never reset, or reset failed: only `reset` is allowed.
    NeedsReset,
    Running,
    /// The episode ended: `step` needs a `reset`; the other methods still see its state.
    Ended,
}

impl Phase {
    /// Refuses with [`EnvError::NeedsReset`] before the first `reset`.
    pub fn started(self) -> Result<(), EnvError> {
        match self {
            Phase::NeedsReset => Err(EnvError::NeedsReset),
            Phase::Running | Phase::Ended => Ok(()),
        }
    }

    /// Refuses with [`EnvError::NeedsReset`] unless an episode is running (`step`).
    pub fn running(self) -> Result<(), EnvError> {
        match self {
            Phase::Running => Ok(()),
            Phase::NeedsReset | Phase::Ended => Err(EnvError::NeedsReset),
        }
    }

    /// The [`StepOutcome`] of `outcome` after the episode's `steps`-th control period:
    /// truncated at `max_episode_steps` unless it terminated. Either ends the episode.
    pub fn finish_step(
        &mut self,
        outcome: Outcome,
        steps: u32,
        max_episode_steps: u32,
    ) -> StepOutcome {
        let truncated = !outcome.terminated && steps >= max_episode_steps;
        if outcome.terminated || truncated {
            *self = Phase::Ended;
        }
        StepOutcome {
            reward: outcome.reward,
            terminated: outcome.terminated,
            truncated,
        }
    }
}

/// What a task tells about one state: Gymnasium's reward and termination. Its info goes
/// into an [`Info`] the caller owns, the same keys at every step and at reset (datasets
/// store them as columns).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outcome {
    pub reward: f64,
    pub terminated: bool,
}

/// The result of one [`Env::step`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Step {
    pub observation: Vec<f64>,
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    pub info: Info,
}

/// The result of one [`Env::step_into`]: a [`Step`] but its observation and info, which
/// went into the caller's buffers. Small enough to come back in registers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepOutcome {
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
}

impl StepOutcome {
    /// The [`Step`] of this outcome, its observation and its info.
    pub fn with_observation(self, observation: Vec<f64>, info: Info) -> Step {
        Step {
            observation,
            reward: self.reward,
            terminated: self.terminated,
            truncated: self.truncated,
            info,
        }
    }
}

/// A task with Gymnasium semantics.
///
/// Seeding follows Gymnasium: `reset(Some(seed))` reseeds the RNG, `reset(None)` continues
/// from the current RNG state, so two runs with the same seed sequence are identical.
pub trait Env: Send {
    fn spec(&self) -> &EnvSpec;

    /// Starts an episode and returns the first observation.
    fn reset(
        &mut self,
        seed: Option<u64>,
        options: &ResetOptions,
    ) -> Result<(Vec<f64>, Info), EnvError>;

    /// Applies the desired acceleration for one control period.
    fn step(&mut self, action: &[f64]) -> Result<Step, EnvError> {
        let mut observation = vec![0.0; self.spec().observation_space.dim()];
        let mut info = Info::new();
        let outcome = self.step_into(action, &mut observation, &mut info)?;
        Ok(outcome.with_observation(observation, info))
    }

    /// [`step`](Self::step) with the observation written into `observation` (its length
    /// checked before anything moves) and the info into `info` (cleared first, its memory
    /// kept), for callers that step many environments into buffers of their own: a step
    /// then allocates nothing, and copies no info from one place to the next.
    fn step_into(
        &mut self,
        action: &[f64],
        observation: &mut [f64],
        info: &mut Info,
    ) -> Result<StepOutcome, EnvError>;

    /// The expert's action for the current state and context.
    fn expert_action(&self) -> Result<Vec<f64>, EnvError>;

    /// Replaces the context mid-episode.
    fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError>;

    /// Whether the task accepts `context` (as a reset option or in `set_context`), without
    /// changing anything: inside the context space and, for some tasks, further conditions
    /// such as obstacles clear of the start and the goal.
    fn check_context(&self, context: &[f64]) -> Result<(), EnvError> {
        self.spec().context_space.check("context", context)
    }

    /// Schedules an external perturbation in simulated time.
    fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError>;

    /// Renders the current state as an RGB image, row-major `height × width × 3`.
    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError>;

    /// Whether steps record the trail [`render`](Self::render) draws behind the robot (on
    /// when made; turning it off frees it). An episode's trail can outweigh the rest of
    /// the environment, so an engine turns it off for the environments of a batch.
    fn record_trail(&mut self, recording: bool);

    /// The task's bodies at `observation` (state then context, as `step` returns it): the
    /// robot, the context's objects (pot, obstacles, target, outline), what viewers show.
    /// It depends on the observation and the construction arguments only, so a fresh
    /// environment draws any recorded or streamed observation without a reset.
    fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError>;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::Dtype;

    fn spec(bound: f64) -> EnvSpec {
        let space = |n: usize| BoxSpace::new(vec![-bound; n], vec![bound; n], Dtype::Float64);
        EnvSpec {
            id: "ciflow/Test-v0".into(),
            observation_space: space(6),
            action_space: space(2),
            context_space: space(2),
            control_dt: 0.01,
            physics_dt: 0.001,
            max_episode_steps: 10,
        }
    }

    /// Equal specs share one copy while one lives; an unequal one gets its own; the cache
    /// keeps none alive.
    #[test]
    fn equal_specs_share_one_copy_and_none_is_kept_alive() {
        let (a, b, other) = (spec(2.0).shared(), spec(2.0).shared(), spec(3.0).shared());
        assert!(Arc::ptr_eq(&a, &b));
        assert!(!Arc::ptr_eq(&a, &other));
        assert_eq!(*other, spec(3.0));
        let weak = Arc::downgrade(&a);
        drop((a, b));
        assert!(weak.upgrade().is_none());
    }
}
