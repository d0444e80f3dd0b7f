//! A trained checkpoint acting in a task's environment: observation in, action out.
//!
//! Every task observes `o = [q, q̇, c]` (position, velocity, context) and takes the
//! desired acceleration `q̈_des` as its action (the computed-torque layer turns it into
//! torques). A flow policy answers with
//!
//! `q̈_des = (∂v_des/∂q) q̇ + K_v (v_des(q, c) − q̇)`,  `v_des = J_f(z) v(z)`, `z = f⁻¹(q, c)`
//!
//! ([`Policy::acceleration`]), so the velocity error decays as `e^{−K_v t}` while the
//! position follows the stable flow; held for a control period, it is shortened along
//! the motion where the field is too stiff for the period ([`Policy::acceleration_held`],
//! `ciflow_engine::flow::sampled_control`). The action is then clipped to the task's action
//! space, as a real robot saturates its commands; far from the demonstrations, where the
//! flow may ask for more, this is the saturated loop that `ciflow_evaluation::robot_loop`
//! measures. The behaviour-cloning baseline acts through the same law and guard on its
//! finite-difference velocity `v = (ŷ_{k+1} − q) / dt`, the derivative along `q̇` taken by
//! a central difference (it has no dual pass), so that the two models differ only in
//! their fields.

use std::path::Path;
use std::sync::Arc;

use ciflow_engine::flow::baseline::BaselineWorkspace;
use ciflow_engine::flow::checkpoint;
use ciflow_engine::flow::sampled_control::limit_overshoot;
use ciflow_engine::flow::{
    BehaviourCloning, CheckpointConfig, EndStopHold, FlowError, Policy, PolicyWorkspace, Weights,
};

use crate::env::EnvSpec;
use crate::space::{BoxSpace, Dtype};

/// The task id of a policy acting on its own data ([`Model::own_data_spec`]).
pub const OWN_DATA_TASK: &str = "own-data";

/// Velocity-feedback gain `K_v` (1/s): the velocity error's time constant is 0.1 s, ten
/// control periods of the slowest task.
pub const DEFAULT_VELOCITY_GAIN: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(
        "checkpoint of task `{checkpoint}` ({state_dim}-D state, {context_dim}-D context) \
         cannot act in `{env}` (observations of {observation_dim}, actions of {action_dim})"
    )]
    Mismatch {
        checkpoint: String,
        state_dim: usize,
        context_dim: usize,
        env: String,
        observation_dim: usize,
        action_dim: usize,
    },
    #[error("observation has {found} elements, expected {expected}")]
    ObservationDim { expected: usize, found: usize },
    #[error("action buffer has {found} elements, expected {expected}")]
    ActionDim { expected: usize, found: usize },
    #[error("velocity gain K_v must be finite and > 0, got {0}")]
    VelocityGain(f64),
}

/// A loaded checkpoint: the stable flow or its unconstrained baseline. The weights are
/// shared: clones, and the [`Actor`]s built from a model, refer to the same ones.
#[derive(Clone, Debug)]
pub enum Model {
    Flow(Arc<Policy>),
    Baseline(Arc<BehaviourCloning>),
}

impl From<Policy> for Model {
    fn from(policy: Policy) -> Self {
        Self::Flow(Arc::new(policy))
    }
}

impl From<BehaviourCloning> for Model {
    fn from(baseline: BehaviourCloning) -> Self {
        Self::Baseline(Arc::new(baseline))
    }
}

impl Model {
    /// Loads whichever model `dir` holds; `expected_task` guards against the wrong task.
    pub fn load(dir: &Path, expected_task: Option<&str>) -> Result<Self, FlowError> {
        let (config, weights) = checkpoint::read(dir, expected_task)?;
        Self::new(&config, weights)
    }

    /// A checkpoint received in memory: the `config.json` text and the safetensors bytes.
    pub fn from_bytes(
        config_json: &str,
        weights: &[u8],
        expected_task: Option<&str>,
    ) -> Result<Self, FlowError> {
        let (config, weights) = checkpoint::from_bytes(config_json, weights, expected_task)?;
        Self::new(&config, weights)
    }

    /// The model a configuration describes, with its weights (shapes checked).
    pub fn new(config: &CheckpointConfig, weights: Weights) -> Result<Self, FlowError> {
        Ok(match config {
            CheckpointConfig::Flow(config) => Policy::new(config, weights)?.into(),
            CheckpointConfig::MlpBaseline(config) => BehaviourCloning::new(config, weights)?.into(),
        })
    }

    /// The flow, or `None` for the baseline (which has no density, latent space or
    /// desired acceleration).
    pub fn flow(&self) -> Option<&Policy> {
        match self {
            Self::Flow(policy) => Some(policy),
            Self::Baseline(_) => None,
        }
    }

    /// The task name recorded in the checkpoint.
    pub fn task(&self) -> &str {
        match self {
            Self::Flow(policy) => &policy.config().task,
            Self::Baseline(baseline) => &baseline.config().task,
        }
    }

    /// The task's construction arguments recorded in the checkpoint (none for checkpoints
    /// trained on the task's defaults).
    pub fn task_kwargs(&self) -> Result<crate::registry::Kwargs, crate::env::EnvError> {
        crate::kwargs::from_json(match self {
            Self::Flow(policy) => &policy.config().task_kwargs,
            Self::Baseline(baseline) => &baseline.config().task_kwargs,
        })
    }

    pub fn state_dim(&self) -> usize {
        match self {
            Self::Flow(policy) => policy.config().state_dim,
            Self::Baseline(baseline) => baseline.config().state_dim,
        }
    }

    pub fn context_dim(&self) -> usize {
        match self {
            Self::Flow(policy) => policy.config().context_dim,
            Self::Baseline(baseline) => baseline.config().context_dim,
        }
    }

    /// The modelled period `dt` (s).
    pub fn dt(&self) -> f64 {
        match self {
            Self::Flow(policy) => policy.config().dt,
            Self::Baseline(baseline) => baseline.config().dt,
        }
    }

    /// What the model acts on where no task environment fits it (a checkpoint trained on
    /// data from elsewhere, `ciflow train --state`): observations `[q, q̇, c]` of its own
    /// dimensions and actions `q̈_des`, unbounded (no actuator to saturate), held for its
    /// period `dt`.
    pub fn own_data_spec(&self) -> EnvSpec {
        let (d, c) = (self.state_dim(), self.context_dim());
        let unbounded = |n: usize| {
            BoxSpace::new(
                vec![f64::NEG_INFINITY; n],
                vec![f64::INFINITY; n],
                Dtype::Float64,
            )
        };
        EnvSpec {
            id: OWN_DATA_TASK.to_owned(),
            observation_space: unbounded(2 * d + c),
            action_space: unbounded(d),
            context_space: unbounded(c),
            control_dt: self.dt(),
            physics_dt: self.dt(),
            max_episode_steps: u32::MAX,
        }
    }
}

/// A model with the buffers it is evaluated in. Each kind carries its own, so a model
/// cannot meet the buffers of the other kind.
enum Controller {
    Flow {
        policy: Arc<Policy>,
        workspace: Box<PolicyWorkspace>,
        /// The current episode's end-stop hold: the latent reference the policy follows
        /// while the barrier holds the robot back.
        hold: EndStopHold,
    },
    Baseline {
        baseline: Arc<BehaviourCloning>,
        workspace: BaselineWorkspace,
        /// `ŷ_{k+1}`, the baseline's predicted next position.
        next: Vec<f64>,
        /// `q ± h q̇` and the predictions there, for the derivative of `v` along `q̇`.
        shifted: Vec<f64>,
        ahead: Vec<f64>,
        behind: Vec<f64>,
        /// The control period `Δt` of the overshoot guard.
        period: f64,
    },
}

/// The time `h` (s) along `q̇` of the baseline's central difference
/// `(∂v/∂q) q̇ ≈ (v(q + h q̇) − v(q − h q̇)) / 2h`: its truncation error (`h²` = 1e-8
/// times the field's third derivative along `q̇`) and its rounding error (machine epsilon
/// over `h`, about 1e-12 relative) are both negligible beside the command.
const FEED_FORWARD_STEP: f64 = 1e-4;

impl Controller {
    fn new(model: &Model, control_period: f64) -> Result<Self, ActorError> {
        Ok(match model {
            Model::Flow(policy) => Self::Flow {
                workspace: Box::new(policy.workspace()),
                hold: EndStopHold::new(policy.config().state_dim, control_period)?,
                policy: Arc::clone(policy),
            },
            Model::Baseline(baseline) => {
                let d = baseline.config().state_dim;
                Self::Baseline {
                    workspace: baseline.workspace(),
                    next: vec![0.0; d],
                    shifted: vec![0.0; d],
                    ahead: vec![0.0; d],
                    behind: vec![0.0; d],
                    period: control_period,
                    baseline: Arc::clone(baseline),
                }
            }
        })
    }
}

/// A [`Model`] with its buffers, acting on one environment's observations. Acting is
/// allocation-free; create one actor per thread. Actors of one model share its weights,
/// so a pool of them costs one set of buffers each.
pub struct Actor {
    controller: Controller,
    state_dim: usize,
    observation_dim: usize,
    velocity_gain: f64,
    action_space: BoxSpace,
    velocity: Vec<f64>,
}

impl Actor {
    /// An actor of `model` for environments of `spec`: the observation must be
    /// `[q, q̇, c]` with `q` and `c` of the model's dimensions and the action `q̈_des`.
    pub fn new(model: &Model, spec: &EnvSpec, velocity_gain: f64) -> Result<Self, ActorError> {
        if !(velocity_gain.is_finite() && velocity_gain > 0.0) {
            return Err(ActorError::VelocityGain(velocity_gain));
        }
        let (d, c) = (model.state_dim(), model.context_dim());
        let (observation_dim, action_dim) = (spec.observation_space.dim(), spec.action_space.dim());
        if observation_dim != 2 * d + c || action_dim != d || spec.context_space.dim() != c {
            return Err(ActorError::Mismatch {
                checkpoint: model.task().to_owned(),
                state_dim: d,
                context_dim: c,
                env: spec.id.clone(),
                observation_dim,
                action_dim,
            });
        }
        Ok(Self {
            controller: Controller::new(model, spec.control_dt)?,
            state_dim: d,
            observation_dim,
            velocity_gain,
            action_space: spec.action_space.clone(),
            velocity: vec![0.0; d],
        })
    }

    pub fn observation_dim(&self) -> usize {
        self.observation_dim
    }

    /// Starts a new episode: a flow's actor releases its end-stop hold ([`EndStopHold`]),
    /// the one thing it keeps from one [`act`](Self::act) to the next.
    pub fn reset(&mut self) {
        if let Controller::Flow { hold, .. } = &mut self.controller {
            hold.clear();
        }
    }

    /// Writes the desired acceleration for `observation = [q, q̇, c]`, clipped to the
    /// action space, to `action`. Successive calls are one episode of one robot, until
    /// [`reset`](Self::reset).
    pub fn act(&mut self, observation: &[f64], action: &mut [f64]) -> Result<(), ActorError> {
        let d = self.state_dim;
        if observation.len() != self.observation_dim {
            return Err(ActorError::ObservationDim {
                expected: self.observation_dim,
                found: observation.len(),
            });
        }
        if action.len() != d {
            return Err(ActorError::ActionDim {
                expected: d,
                found: action.len(),
            });
        }
        let (q, rest) = observation.split_at(d);
        let (qd, context) = rest.split_at(d);
        let gain = self.velocity_gain;
        match &mut self.controller {
            Controller::Flow {
                policy,
                workspace,
                hold,
            } => {
                let velocity = &mut self.velocity;
                policy
                    .acceleration_held(q, qd, context, gain, hold, workspace, action, velocity)?;
            }
            Controller::Baseline {
                baseline,
                workspace,
                next,
                shifted,
                ahead,
                behind,
                period,
            } => {
                // The flow's law `q̈ = (∂v/∂q) q̇ + K_v (v − q̇)` and its overshoot guard, so
                // that the two models are compared through the same controller. The
                // baseline's `v(q) = (ŷ(q) − q) / dt` has no dual pass: its derivative
                // along `q̇` is a central difference, in which `v(q ± h q̇)` differ by
                // `(ŷ(q + h q̇) − ŷ(q − h q̇) − 2h q̇) / dt`.
                baseline.mean_next(q, context, workspace, next)?;
                let h = FEED_FORWARD_STEP;
                for (sign, prediction) in [(1.0, &mut *ahead), (-1.0, &mut *behind)] {
                    for ((s, q), qd) in shifted.iter_mut().zip(q).zip(qd) {
                        *s = q + sign * h * qd;
                    }
                    baseline.mean_next(shifted, context, workspace, prediction)?;
                }
                let dt = baseline.config().dt;
                for i in 0..d {
                    self.velocity[i] = (next[i] - q[i]) / dt;
                    let feed_forward = ((ahead[i] - behind[i]) / (2.0 * h) - qd[i]) / dt;
                    action[i] = feed_forward + gain * (self.velocity[i] - qd[i]);
                }
                limit_overshoot(qd, &self.velocity, gain, *period, action);
            }
        }
        let BoxSpace { low, high, .. } = &self.action_space;
        for ((a, lo), hi) in action.iter_mut().zip(low).zip(high) {
            *a = a.clamp(*lo, *hi);
        }
        Ok(())
    }

    /// The desired velocity of the last [`act`](Self::act) call: `v_des(q, c)` of a flow,
    /// the finite-difference velocity of the baseline.
    pub fn desired_velocity(&self) -> &[f64] {
        &self.velocity
    }
}
