//! [`CheckpointPolicy`]: a trained checkpoint (stable flow or baseline) served as a
//! [`Policy`], acting through [`ciflow_envs::actor::Actor`] on observations `[q, q̇, c]`
//! of the task it was trained for, or of its own data when it was trained on data from
//! elsewhere ([`CheckpointPolicy::on_own_data`]).

use std::path::Path;
use std::sync::Mutex;

use ciflow_engine::flow::FlowError;
use ciflow_envs::actor::{Actor, ActorError, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::{EnvError, EnvSpec};

use crate::policy::{Policy, PolicyError};
use crate::protocol::keys;
use crate::protocol::{CheckpointMsg, PolicyInfo};
use ciflow_envs::registry::Kwargs;

use crate::task_factory::TaskFactory;

/// Why a checkpoint cannot be served.
#[derive(Debug, thiserror::Error)]
pub enum PolicyLoadError {
    /// Missing or malformed files, weights of the wrong shapes, wrong model kind.
    #[error("{0}")]
    Checkpoint(#[from] FlowError),
    #[error(
        "checkpoint is for task `{task}`, which this engine does not serve (it has: {available})"
    )]
    UnknownTask { task: String, available: String },
    #[error("task `{task}` cannot be built with the policy's arguments: {source}")]
    Task { task: String, source: EnvError },
    /// The checkpoint's dimensions do not fit the task's observations and actions.
    #[error("{0}")]
    Shape(#[from] ActorError),
    #[error("policy name `{0}` must be letters, digits, `-`, `_` or `.`")]
    BadName(String),
    #[error("publication on policy `{key}` names policy `{name}`")]
    NameMismatch { key: String, name: String },
    #[error("publication claims task `{claimed}` but its configuration says `{found}`")]
    TaskMismatch { claimed: String, found: String },
}

/// A checkpoint acting in its task. Each concurrent caller borrows an [`Actor`] (the
/// shared weights plus its own buffers) from a pool, so acting allocates nothing once
/// the pool is warm.
pub struct CheckpointPolicy {
    info: PolicyInfo,
    kwargs: Kwargs,
    model: Model,
    spec: EnvSpec,
    actors: Mutex<Vec<Actor>>,
}

impl CheckpointPolicy {
    /// Serves `model` as `name` (default: the checkpoint's task name) in the task of
    /// `tasks` it was trained for, built with the construction arguments `kwargs` (none:
    /// those the checkpoint recorded).
    pub fn new(
        name: Option<&str>,
        model: Model,
        tasks: &[TaskFactory],
        kwargs: &Kwargs,
    ) -> Result<Self, PolicyLoadError> {
        let factory = tasks
            .iter()
            .find(|t| t.is_named(model.task()))
            .ok_or_else(|| PolicyLoadError::UnknownTask {
                task: model.task().to_owned(),
                available: tasks
                    .iter()
                    .map(|t| t.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        let task_error = |source| PolicyLoadError::Task {
            task: factory.id.clone(),
            source,
        };
        let kwargs = match kwargs.is_empty() {
            true => model.task_kwargs().map_err(task_error)?,
            false => kwargs.clone(),
        };
        let spec = (factory.make)(&kwargs).map_err(task_error)?.spec().clone();
        Self::serving(name, model, spec, kwargs)
    }

    /// Serves `model` as `name` (default: the checkpoint's task name) acting on its own
    /// data's observations, with no task environment ([`Model::own_data_spec`]): a
    /// checkpoint trained on data from elsewhere, whose shapes fit none of the tasks.
    /// Clients `act` with it (a session whose observations happen to have its shapes can
    /// run it too: only the shapes are checked there).
    pub fn on_own_data(name: Option<&str>, model: Model) -> Result<Self, PolicyLoadError> {
        let spec = model.own_data_spec();
        Self::serving(name, model, spec, Kwargs::new())
    }

    /// `model` served as `name` (default: its task name) in `spec`, built with `kwargs`.
    fn serving(
        name: Option<&str>,
        model: Model,
        spec: EnvSpec,
        kwargs: Kwargs,
    ) -> Result<Self, PolicyLoadError> {
        let name = name.unwrap_or(model.task()).to_owned();
        if !keys::is_plain_chunk(&name) {
            return Err(PolicyLoadError::BadName(name));
        }
        // Building the first actor checks the shapes; it then seeds the pool.
        let actor = Actor::new(&model, &spec, DEFAULT_VELOCITY_GAIN)?;
        Ok(Self {
            info: PolicyInfo {
                name,
                task: spec.id.clone(),
                observation_dim: spec.observation_space.dim() as u32,
                action_dim: spec.action_space.dim() as u32,
                epoch: None,
                validation_nll: None,
            },
            kwargs,
            model,
            spec,
            actors: Mutex::new(vec![actor]),
        })
    }

    /// Loads the checkpoint directory `dir` (`config.json`, `weights.safetensors`).
    pub fn load(
        name: Option<&str>,
        dir: &Path,
        tasks: &[TaskFactory],
        kwargs: &Kwargs,
    ) -> Result<Self, PolicyLoadError> {
        Self::new(name, Model::load(dir, None)?, tasks, kwargs)
    }

    /// A checkpoint received as a publication; the message's name and task must agree
    /// with the key it came on and with its configuration. `kwargs` apply unless the
    /// message carries its own.
    pub fn from_message(
        key_name: &str,
        message: &CheckpointMsg,
        tasks: &[TaskFactory],
        kwargs: &Kwargs,
    ) -> Result<Self, PolicyLoadError> {
        let model = Self::published_model(key_name, message, tasks)?;
        let kwargs = if message.kwargs.is_empty() {
            kwargs
        } else {
            &message.kwargs
        };
        let policy = Self::new(Some(&message.name), model, tasks, kwargs)?;
        Ok(policy.published_at(message))
    }

    /// A checkpoint received as a publication, served on its own data's observations
    /// ([`on_own_data`](Self::on_own_data)): the next checkpoint of a policy trained on
    /// data from elsewhere. Name and task are checked as by
    /// [`from_message`](Self::from_message); the message's task arguments have no task
    /// to apply to and are ignored.
    pub fn from_message_on_own_data(
        key_name: &str,
        message: &CheckpointMsg,
        tasks: &[TaskFactory],
    ) -> Result<Self, PolicyLoadError> {
        let model = Self::published_model(key_name, message, tasks)?;
        let policy = Self::on_own_data(Some(&message.name), model)?;
        Ok(policy.published_at(message))
    }

    /// The model a publication carries, once its name agrees with the key it came on and
    /// its task with its configuration.
    fn published_model(
        key_name: &str,
        message: &CheckpointMsg,
        tasks: &[TaskFactory],
    ) -> Result<Model, PolicyLoadError> {
        if message.name != key_name {
            return Err(PolicyLoadError::NameMismatch {
                key: key_name.to_owned(),
                name: message.name.clone(),
            });
        }
        let model = Model::from_bytes(&message.config, &message.weights, None)?;
        // The message may name the task by its Gymnasium id (as `PolicyInfo.task` does)
        // or its short name, whichever the configuration holds.
        let names_task = |task: &str| {
            task == model.task()
                || tasks
                    .iter()
                    .any(|t| t.is_named(model.task()) && t.is_named(task))
        };
        if !names_task(&message.task) {
            return Err(PolicyLoadError::TaskMismatch {
                claimed: message.task.clone(),
                found: model.task().to_owned(),
            });
        }
        Ok(model)
    }

    /// This policy with the training figures `message` came with.
    fn published_at(mut self, message: &CheckpointMsg) -> Self {
        self.info.epoch = Some(message.epoch);
        self.info.validation_nll = Some(message.validation_nll);
        self
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The task specification the policy acts in.
    pub fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn actor(&self) -> Result<Actor, PolicyError> {
        let pooled = self.actors.lock().unwrap_or_else(|p| p.into_inner()).pop();
        match pooled {
            Some(actor) => Ok(actor),
            None => Ok(Actor::new(&self.model, &self.spec, DEFAULT_VELOCITY_GAIN)?),
        }
    }
}

impl Policy for CheckpointPolicy {
    fn info(&self) -> PolicyInfo {
        self.info.clone()
    }

    fn task_kwargs(&self) -> Kwargs {
        self.kwargs.clone()
    }

    fn model(&self) -> Option<&Model> {
        Some(&self.model)
    }

    fn act_into(&self, observation: &[f64], action: &mut [f64]) -> Result<(), PolicyError> {
        // A query is one observation of any robot: pooled actors keep nothing between
        // queries, so none is held at an end stop ([`Actor::reset`]).
        let mut actor = self.actor()?;
        actor.reset();
        let result = actor.act(observation, action).map_err(PolicyError::from);
        self.actors
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(actor);
        result
    }
}
