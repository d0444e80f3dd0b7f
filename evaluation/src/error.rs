//! Why an evaluation could not run.

use ciflow_engine::flow::FlowError;
use ciflow_envs::actor::ActorError;
use ciflow_envs::env::EnvError;

#[derive(Debug, thiserror::Error)]
pub enum EvaluationError {
    #[error(transparent)]
    Env(#[from] EnvError),
    #[error(transparent)]
    Actor(#[from] ActorError),
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(transparent)]
    Model(#[from] ciflow_engine::model::ModelError),
    #[error(transparent)]
    RobotLoop(#[from] crate::robot_loop::RobotLoopError),
    #[error("invalid evaluation setting: {0}")]
    InvalidConfig(String),
    #[error(transparent)]
    Subset(#[from] ciflow_envs::learning_curve::TooFewEpisodes),
    #[error("no valid new context found for the episode of seed {seed} in {tries} draws")]
    NoValidContext { seed: u64, tries: usize },
    /// Work run elsewhere (engines over Zenoh) failed there.
    #[error("the rollouts run elsewhere failed")]
    Remote(#[source] Box<dyn std::error::Error + Send + Sync>),
}

pub type EvaluationResult<T> = Result<T, EvaluationError>;
