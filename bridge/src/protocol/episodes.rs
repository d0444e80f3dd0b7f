//! Finished demonstration episodes on the wire: one MessagePack map per episode, published
//! (never queried: an episode can be megabytes) on
//! [`keys::episodes`](super::keys::episodes) `ciflow/v2/episodes/<task>/<recorder>` by
//! recorders as each episode ends, and collected by trainers subscribed to
//! `ciflow/v2/episodes/<task>/*`.
//!
//! An episode of `T` steps carries, row-major, `T + 1` observations and contexts (the reset
//! row first) and `T` actions and rewards, exactly the rows of a dataset episode
//! ([`ciflow_envs::dataset::Episode`]); [`EpisodeMsg::from_dataset`] and
//! [`EpisodeMsg::into_dataset`] convert both ways without loss.

use std::collections::BTreeMap;

use ciflow_envs::BoxSpace;
use ciflow_envs::dataset::{Credits, DatasetSpec, Episode};
use ciflow_envs::registry::Kwargs;
use serde::{Deserialize, Serialize};

use super::{F64s, Header, PROTOCOL_VERSION};

/// `algorithm_name` of datasets rebuilt from the channel: recorders publish expert rollouts.
pub const EPISODE_ALGORITHM: &str = "expert";

/// One finished episode, published on `ciflow/v2/episodes/<task>/<recorder>`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeMsg {
    pub v: u16,
    /// Gymnasium id of the task, e.g. `ciflow/Pouring-v0`.
    pub task: String,
    /// The task's construction arguments, e.g. `{"obstacles": 2}` (none: its defaults).
    #[serde(default)]
    pub kwargs: Kwargs,
    /// The publishing recorder, the last chunk of the key.
    pub recorder: String,
    /// Minari id of the dataset the recorder writes, e.g. `ciflow/pouring-expert-v0`.
    pub dataset_id: String,
    /// Position of the episode in its recorder's dataset (0, 1, …).
    pub index: u64,
    /// The seed passed to `reset`.
    pub seed: Option<u64>,
    /// Seconds between consecutive observations.
    pub control_dt: f64,
    pub observation_dim: u32,
    pub action_dim: u32,
    pub context_dim: u32,
    /// The task's spaces (bounds of the dataset's metadata); their dimensions are the
    /// three above.
    pub observation_space: BoxSpace,
    pub action_space: BoxSpace,
    pub context_space: BoxSpace,
    /// `(T + 1) × observation_dim`, the reset observation first.
    pub observations: F64s,
    /// `T × action_dim`; `actions[t]` led from observation `t` to `t + 1`.
    pub actions: F64s,
    /// `(T + 1) × context_dim`, aligned with the observations.
    pub contexts: F64s,
    /// `T` rewards.
    pub rewards: F64s,
    /// How the last step ended the episode (every earlier step continued it).
    pub terminated: bool,
    pub truncated: bool,
    /// Scalar info series, `T + 1` values each (the reset info first). Optional.
    #[serde(default)]
    pub infos: BTreeMap<String, F64s>,
}

/// Why a published episode could not be used.
#[derive(Debug, thiserror::Error)]
pub enum EpisodeError {
    #[error("episode message has protocol version {got}, this build speaks {PROTOCOL_VERSION}")]
    VersionMismatch { got: u16 },
    #[error("episode message is not a MessagePack map of the episode layout")]
    Malformed(#[source] rmp_serde::decode::Error),
    #[error("episode {index} of recorder `{recorder}`: {detail}")]
    Inconsistent {
        recorder: String,
        index: u64,
        detail: String,
    },
    #[error("episode {index} of recorder `{recorder}`: {what} contain NaN or inf")]
    NotFinite {
        recorder: String,
        index: u64,
        what: &'static str,
    },
}

impl EpisodeMsg {
    /// The message of dataset episode `episode`, number `index` of `recorder`'s dataset
    /// described by `spec`.
    pub fn from_dataset(recorder: &str, index: u64, spec: &DatasetSpec, episode: &Episode) -> Self {
        let flat = |rows: &[Vec<f64>]| F64s(rows.concat());
        let dim = |space: &BoxSpace| space.dim() as u32;
        Self {
            v: PROTOCOL_VERSION,
            task: spec.env_id.clone(),
            kwargs: spec.env_kwargs.clone(),
            recorder: recorder.to_owned(),
            dataset_id: spec.dataset_id.clone(),
            index,
            seed: episode.seed,
            control_dt: spec.control_dt,
            observation_dim: dim(&spec.observation_space),
            action_dim: dim(&spec.action_space),
            context_dim: dim(&spec.context_space),
            observation_space: spec.observation_space.clone(),
            action_space: spec.action_space.clone(),
            context_space: spec.context_space.clone(),
            observations: flat(&episode.observations),
            actions: flat(&episode.actions),
            contexts: flat(&episode.contexts),
            rewards: F64s(episode.rewards.clone()),
            terminated: episode.terminations.last().copied().unwrap_or(false),
            truncated: episode.truncations.last().copied().unwrap_or(false),
            infos: episode
                .infos
                .iter()
                .map(|(name, series)| (name.clone(), F64s(series.clone())))
                .collect(),
        }
    }

    /// The dataset description this episode belongs to.
    pub fn dataset_spec(&self) -> DatasetSpec {
        DatasetSpec {
            dataset_id: self.dataset_id.clone(),
            env_id: self.task.clone(),
            env_kwargs: self.kwargs.clone(),
            observation_space: self.observation_space.clone(),
            action_space: self.action_space.clone(),
            context_space: self.context_space.clone(),
            control_dt: self.control_dt,
            algorithm_name: EPISODE_ALGORITHM.to_owned(),
            credits: Credits::default(),
        }
    }

    /// Checks every shape and value, then splits the message into its dataset
    /// description and its episode.
    pub fn into_dataset(self) -> Result<(DatasetSpec, Episode), EpisodeError> {
        self.validate()?;
        let spec = self.dataset_spec();
        let steps = self.rewards.0.len();
        // `count` rows of `dim` values; counted, since zero-width rows hold no values.
        let rows = |values: Vec<f64>, dim: u32, count: usize| -> Vec<Vec<f64>> {
            match dim {
                0 => vec![Vec::new(); count],
                dim => values
                    .chunks_exact(dim as usize)
                    .map(<[f64]>::to_vec)
                    .collect(),
            }
        };
        let flags = |last: bool| {
            let mut flags = vec![false; steps];
            if let Some(flag) = flags.last_mut() {
                *flag = last;
            }
            flags
        };
        let episode = Episode {
            seed: self.seed,
            observations: rows(self.observations.0, self.observation_dim, steps + 1),
            actions: rows(self.actions.0, self.action_dim, steps),
            rewards: self.rewards.0,
            terminations: flags(self.terminated),
            truncations: flags(self.truncated),
            contexts: rows(self.contexts.0, self.context_dim, steps + 1),
            infos: self
                .infos
                .into_iter()
                .map(|(name, series)| (name, series.0))
                .collect(),
        };
        Ok((spec, episode))
    }

    fn validate(&self) -> Result<(), EpisodeError> {
        let inconsistent = |detail: String| EpisodeError::Inconsistent {
            recorder: self.recorder.clone(),
            index: self.index,
            detail,
        };
        if self.v != PROTOCOL_VERSION {
            return Err(EpisodeError::VersionMismatch { got: self.v });
        }
        if !(self.control_dt.is_finite() && self.control_dt > 0.0) {
            return Err(inconsistent(format!(
                "control_dt {} is not a positive number",
                self.control_dt
            )));
        }
        let spaces = [
            ("observation", &self.observation_space, self.observation_dim),
            ("action", &self.action_space, self.action_dim),
            ("context", &self.context_space, self.context_dim),
        ];
        for (name, space, dim) in spaces {
            if space.low.len() != space.high.len() || space.dim() != dim as usize {
                return Err(inconsistent(format!(
                    "{name} space has {} lower and {} upper bounds, {name}_dim is {dim}",
                    space.low.len(),
                    space.high.len()
                )));
            }
        }
        if self.observation_dim == 0 {
            return Err(inconsistent("observation_dim is 0".into()));
        }
        let steps = self.rewards.0.len();
        if steps == 0 {
            return Err(inconsistent("an episode needs at least one step".into()));
        }
        let lengths = [
            (
                "observations",
                &self.observations,
                steps + 1,
                self.observation_dim,
            ),
            ("actions", &self.actions, steps, self.action_dim),
            ("contexts", &self.contexts, steps + 1, self.context_dim),
        ];
        for (name, values, rows, dim) in lengths {
            let expected = rows * dim as usize;
            if values.0.len() != expected {
                return Err(inconsistent(format!(
                    "{name} hold {} values, expected {rows} rows × {dim} = {expected} for \
                     {steps} steps",
                    values.0.len()
                )));
            }
        }
        for (name, series) in &self.infos {
            if series.0.len() != steps + 1 {
                return Err(inconsistent(format!(
                    "info `{name}` has {} values, expected {}",
                    series.0.len(),
                    steps + 1
                )));
            }
        }
        let values = [
            ("observations", &self.observations),
            ("actions", &self.actions),
            ("contexts", &self.contexts),
            ("rewards", &self.rewards),
        ];
        if let Some((what, _)) = values
            .into_iter()
            .find(|(_, values)| values.0.iter().any(|v| !v.is_finite()))
        {
            return Err(EpisodeError::NotFinite {
                recorder: self.recorder.clone(),
                index: self.index,
                what,
            });
        }
        Ok(())
    }
}

/// Decodes a published episode, telling a version mismatch from a malformed payload, and
/// checks its shapes and values (see [`EpisodeMsg::into_dataset`]).
pub fn decode_episode(payload: &[u8]) -> Result<EpisodeMsg, EpisodeError> {
    match rmp_serde::from_slice::<Header>(payload) {
        Ok(Header { v, .. }) if v != PROTOCOL_VERSION => {
            return Err(EpisodeError::VersionMismatch { got: v });
        }
        Ok(_) => {}
        Err(e) => return Err(EpisodeError::Malformed(e)),
    }
    let message: EpisodeMsg = rmp_serde::from_slice(payload).map_err(EpisodeError::Malformed)?;
    message.validate()?;
    Ok(message)
}

#[cfg(test)]
mod tests {
    use ciflow_envs::rollout::{expert_dataset_spec, expert_episode};
    use ciflow_envs::{Dtype, ResetOptions};

    use super::*;
    use crate::protocol::encode;

    fn recorded() -> (DatasetSpec, Episode) {
        let mut env = ciflow_envs::make("obstacle-avoidance").unwrap();
        let spec = expert_dataset_spec(
            env.as_ref(),
            &Default::default(),
            "ciflow/obstacle-avoidance-expert-v0",
        );
        let episode = expert_episode(env.as_mut(), Some(3), &ResetOptions::default()).unwrap();
        (spec, episode)
    }

    #[test]
    fn dataset_episodes_round_trip_through_the_wire() {
        let (spec, episode) = recorded();
        assert!(episode.len() > 1);
        let message = EpisodeMsg::from_dataset("rec-1", 4, &spec, &episode);
        let decoded = decode_episode(&encode(&message)).unwrap();
        assert_eq!(decoded, message);
        assert_eq!(decoded.index, 4);
        let (spec_back, episode_back) = decoded.into_dataset().unwrap();
        assert_eq!(spec_back, spec);
        assert_eq!(episode_back, episode);
    }

    #[test]
    fn bad_episodes_get_typed_errors() {
        let (spec, episode) = recorded();
        let good = EpisodeMsg::from_dataset("rec", 0, &spec, &episode);
        let decode = |message: &EpisodeMsg| decode_episode(&encode(message)).unwrap_err();

        let garbage = decode_episode(b"\x93garbage").unwrap_err();
        assert!(matches!(garbage, EpisodeError::Malformed(_)));
        let cause = std::error::Error::source(&garbage).expect("the decode error is the source");
        assert!(cause.is::<rmp_serde::decode::Error>());
        assert!(matches!(
            decode_episode(&encode(&crate::protocol::TasksRequest {
                v: PROTOCOL_VERSION
            })),
            Err(EpisodeError::Malformed(_))
        ));
        assert!(matches!(
            decode(&EpisodeMsg {
                v: 9,
                ..good.clone()
            }),
            EpisodeError::VersionMismatch { got: 9 }
        ));

        let mut short = good.clone();
        short.observations.0.pop();
        assert!(matches!(decode(&short), EpisodeError::Inconsistent { .. }));

        let mut wrong_dim = good.clone();
        wrong_dim.action_dim += 1;
        assert!(matches!(
            decode(&wrong_dim),
            EpisodeError::Inconsistent { .. }
        ));

        let mut ragged_space = good.clone();
        ragged_space.context_space.high.pop();
        assert!(matches!(
            decode(&ragged_space),
            EpisodeError::Inconsistent { .. }
        ));

        let mut bad_info = good.clone();
        bad_info.infos.insert("time".into(), F64s(vec![0.0]));
        assert!(matches!(
            decode(&bad_info),
            EpisodeError::Inconsistent { .. }
        ));

        let mut nan = good.clone();
        nan.actions.0[0] = f64::NAN;
        assert!(matches!(
            decode(&nan),
            EpisodeError::NotFinite {
                recorder,
                index: 0,
                what: "actions"
            } if recorder == "rec"
        ));

        let mut no_dt = good;
        no_dt.control_dt = 0.0;
        assert!(matches!(decode(&no_dt), EpisodeError::Inconsistent { .. }));
    }

    #[test]
    fn flags_mark_only_the_last_step() {
        let space = |n: usize| BoxSpace::new(vec![-1.0; n], vec![1.0; n], Dtype::Float64);
        let spec = DatasetSpec {
            dataset_id: "ciflow/x-expert-v0".into(),
            env_id: "ciflow/X-v0".into(),
            env_kwargs: Default::default(),
            observation_space: space(3),
            action_space: space(1),
            context_space: space(1),
            control_dt: 0.1,
            algorithm_name: EPISODE_ALGORITHM.into(),
            credits: Default::default(),
        };
        let episode = Episode {
            seed: None,
            observations: vec![vec![0.0, 0.0, 0.5]; 3],
            actions: vec![vec![0.1], vec![0.2]],
            rewards: vec![-1.0, 0.0],
            terminations: vec![false, true],
            truncations: vec![false, false],
            contexts: vec![vec![0.5]; 3],
            infos: BTreeMap::new(),
        };
        let message = EpisodeMsg::from_dataset("r", 0, &spec, &episode);
        assert!(message.terminated && !message.truncated);
        assert_eq!(message.into_dataset().unwrap(), (spec, episode));
    }
}
