//! Log-likelihood of demonstrations under a flow policy, per transition, as the trainer
//! reports its validation score (with the opposite sign):
//!
//! `ℓ = (1/N) Σ_i Σ_{t≥1} log p(y_tⁱ | y_{t−1}ⁱ, c_{t−1}ⁱ)`, `N` the number of transitions,
//!
//! in the data's own units ([`Policy::log_transition`] includes the normalisation
//! Jacobian), with the policy's state `y = q`, the position part of each observation
//! `[q, q̇, c]`, and the per-step context `c`. The sum runs over the transitions the
//! trainer fits by default: those an external force moved ([`Episode::perturbed`]) show
//! the push, not the policy, and are left out. The initial-state term `log p(y₀ | c₀)` is
//! reported separately, per episode.

use ciflow_engine::flow::Policy;
use serde::Serialize;

use ciflow_envs::dataset::Episode;
use ciflow_envs::learning_curve::subset;

use crate::{EvaluationError, EvaluationResult};

/// Outcome of [`log_likelihood`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LogLikelihood {
    pub episodes: usize,
    pub transitions: usize,
    /// `ℓ`: mean `log p(y_t | y_{t−1}, c_{t−1})` over all transitions (nats).
    pub per_transition: f64,
    /// Mean `log p(y₀ | c₀)` over episodes (nats).
    pub initial_per_episode: f64,
}

impl std::fmt::Display for LogLikelihood {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "log-likelihood {:.4} per transition ({} transitions, {} episodes; initial {:.4} \
             per episode)",
            self.per_transition, self.transitions, self.episodes, self.initial_per_episode
        )
    }
}

/// The episodes of a dataset that `ciflow train` fits by default, those that achieved
/// their task, and how many did not; with `count = Some((n, seed))` only `n` of them, as
/// a learning curve picks them ([`subset`]).
pub fn scored_episodes(
    mut episodes: Vec<Episode>,
    count: Option<(usize, u64)>,
) -> EvaluationResult<(Vec<Episode>, usize)> {
    let recorded = episodes.len();
    episodes.retain(|e| !e.failed());
    let failed = recorded - episodes.len();
    if let Some((count, seed)) = count {
        episodes = subset(episodes, count, seed, |e| &e.contexts[0])?;
    }
    Ok((episodes, failed))
}

/// `ℓ` of `policy` on `episodes` (module docs).
pub fn log_likelihood(policy: &Policy, episodes: &[Episode]) -> EvaluationResult<LogLikelihood> {
    let d = policy.config().state_dim;
    let mut ws = policy.workspace();
    let (mut transitions, mut sum, mut initial) = (0usize, 0.0, 0.0);
    for (i, episode) in episodes.iter().enumerate() {
        let (observations, contexts) = (&episode.observations, &episode.contexts);
        if observations.is_empty()
            || contexts.len() != observations.len()
            || observations.iter().any(|o| o.len() < d)
        {
            return Err(EvaluationError::InvalidConfig(format!(
                "episode {i}: {} observations (each at least {d} long) and {} contexts",
                observations.len(),
                contexts.len()
            )));
        }
        initial += policy.log_initial(&observations[0][..d], &contexts[0], &mut ws)?;
        for t in (1..observations.len()).filter(|&t| !episode.perturbed(t - 1)) {
            sum += policy.log_transition(
                &observations[t - 1][..d],
                &observations[t][..d],
                &contexts[t - 1],
                &mut ws,
            )?;
            transitions += 1;
        }
    }
    if transitions == 0 {
        return Err(EvaluationError::InvalidConfig(
            "the dataset has no unperturbed transitions".into(),
        ));
    }
    Ok(LogLikelihood {
        episodes: episodes.len(),
        transitions,
        per_transition: sum / transitions as f64,
        initial_per_episode: initial / episodes.len() as f64,
    })
}
