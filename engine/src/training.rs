//! The settings of a training run, as plain data.
//!
//! Training itself lives in the `ciflow-train` crate (the only libtorch user); its
//! settings live here so that the task registry (`ciflow-envs`) can carry each task's
//! recipe, and a checkpoint's reader can name them, without linking libtorch.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::flow::{
    ContextSet, ContractionConfig, CouplingKind, JointRange, LatentKind, SetEncoderConfig,
};

/// Default [`TrainConfig::state_noise`].
pub const DEFAULT_STATE_NOISE: f64 = 0.1;

/// Architecture and optimisation settings of a flow's training (`ciflow_train::train_flow`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub task: String,
    /// The task's construction arguments, as the demonstrations' dataset recorded them
    /// (e.g. the reach task's URDF document), carried into the checkpoint.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub task_kwargs: BTreeMap<String, serde_json::Value>,
    pub latent: LatentKind,
    pub coupling: CouplingKind,
    pub layers: usize,
    pub hidden: Vec<usize>,
    /// Guaranteed latent contraction rate `ε` (1/s).
    pub min_rate: f64,
    /// `target(c) = c[indices]` for go-to tasks whose target is in the context.
    pub goal_context_indices: Option<Vec<usize>>,
    /// Unordered sets in the context (e.g. obstacle centres) that the conditioners see
    /// through permutation-invariant encoders ([`crate::flow::layers::context_set`]).
    #[serde(default)]
    pub context_sets: Vec<ContextSet>,
    /// The encoders' architecture (used when there are sets).
    #[serde(default)]
    pub set_encoder: SetEncoderConfig,
    /// Radial contractions about context points (e.g. obstacle centres) in front of the
    /// network ([`crate::flow::layers::radial`]).
    #[serde(default)]
    pub contractions: Option<ContractionConfig>,
    /// A robot's limits built into the policy ([`crate::flow::layers::joint_range`]).
    #[serde(default)]
    pub joint_range: Option<JointRange>,
    /// Longest modelled transition: each minibatch row spans `k ~ U{1, …, horizon}` steps
    /// and enters the loss with the exact `k`-step density (1 = the paper's one-step
    /// transitions).
    pub horizon: usize,
    /// Share of the minibatch rows whose span runs to the end of their episode
    /// (`y_t → y_T`, however many steps), so the motion ends where and when the
    /// demonstrations do; 0 leaves them out.
    #[serde(default)]
    pub arrival: f64,
    /// Standard deviation of the Gaussian jitter added to every training state, as a
    /// fraction of the demonstrations' RMS step (per normalised coordinate); 0 trains on
    /// the states as recorded (exact maximum likelihood). Deterministic expert
    /// demonstrations have an unbounded likelihood as the flow contracts onto them, and a
    /// held-out likelihood watched for early stopping can collapse within a few epochs:
    /// jitter gives them a density.
    pub state_noise: f64,
    /// Fraction of episodes held out for early stopping (at least one when there are two);
    /// 0 fits every episode and reports the one-step likelihood of the fitted ones.
    pub validation_fraction: f64,
    /// libtorch intra-op threads (1 suits these small networks).
    pub threads: i32,
    pub optim: OptimConfig,
}

impl TrainConfig {
    pub fn new(task: &str, latent: LatentKind) -> Self {
        Self {
            task: task.to_owned(),
            task_kwargs: BTreeMap::new(),
            latent,
            coupling: CouplingKind::Spline {
                bins: 8,
                tail_bound: 4.0,
            },
            layers: 6,
            hidden: vec![64, 64],
            min_rate: 0.1,
            goal_context_indices: None,
            context_sets: Vec::new(),
            set_encoder: SetEncoderConfig::default(),
            contractions: None,
            joint_range: None,
            horizon: 1,
            arrival: 0.0,
            state_noise: DEFAULT_STATE_NOISE,
            validation_fraction: 0.2,
            threads: 1,
            optim: OptimConfig::default(),
        }
    }

    /// This recipe fitted to every demonstration it is given, none held out for early
    /// stopping, with the last epoch's parameters kept (the training loss stands in for
    /// the validation score): for tasks whose held-out contexts are scored elsewhere, or
    /// whose every demonstration is a context of its own.
    pub fn fitting_every_demonstration(self) -> Self {
        Self {
            validation_fraction: 0.0,
            optim: OptimConfig {
                keep: Keep::Last,
                ..self.optim
            },
            ..self
        }
    }
}

/// Optimiser settings common to the flow and the baseline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OptimConfig {
    pub epochs: usize,
    pub batch_size: usize,
    pub learning_rate: f64,
    /// The cosine schedule decays to `learning_rate · final_lr_fraction`.
    pub final_lr_fraction: f64,
    /// Stop after this many epochs without a better validation score.
    pub patience: usize,
    /// Gradient-norm clip.
    pub max_grad_norm: f64,
    /// Which epoch's parameters training returns.
    pub keep: Keep,
    pub seed: u64,
}

/// Which epoch's parameters training returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Keep {
    /// The epoch with the best validation score (early stopping).
    #[default]
    BestValidation,
    /// The last epoch's: validation only reports, patience still ends training.
    Last,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            epochs: 200,
            batch_size: 256,
            learning_rate: 2e-3,
            final_lr_fraction: 0.05,
            patience: 30,
            max_grad_norm: 50.0,
            keep: Keep::BestValidation,
            seed: 0,
        }
    }
}
