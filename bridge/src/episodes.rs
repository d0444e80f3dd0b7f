//! The episode channel: recorders publish each finished demonstration episode on
//! `ciflow/v2/episodes/<task>/<recorder>` ([`EpisodePublisher`]); trainers subscribe to
//! `ciflow/v2/episodes/<task>/*` and collect a number of them ([`EpisodeSubscriber`],
//! [`collect`]). Pub/sub, reliable (Zenoh's default) and blocking under congestion, so that no episode of a
//! connected subscriber is dropped; episodes published before a subscriber joined are not
//! replayed (start the trainer first).

use std::time::{Duration, Instant};

use ciflow_envs::dataset::{DatasetSpec, Episode};
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;

use crate::config::{NetworkOptions, Role};
use crate::error::BridgeError;
use crate::protocol::keys;
use crate::protocol::{EpisodeError, EpisodeMsg, decode_episode, encode};

/// The command-line name of a task given by name or Gymnasium id (the `<task>` chunk).
fn task_name(task: &str) -> Result<&'static str, BridgeError> {
    ciflow_envs::registry::entry(task)
        .map(|entry| entry.name)
        .map_err(BridgeError::UnknownTask)
}

/// Publishes one recorder's episodes of one task.
pub struct EpisodePublisher {
    publisher: Publisher<'static>,
    recorder: String,
}

impl EpisodePublisher {
    /// Declares the publisher of `recorder` (a plain key chunk) for `task` (name or
    /// Gymnasium id).
    pub fn declare(
        zsession: &zenoh::Session,
        task: &str,
        recorder: &str,
    ) -> Result<Self, BridgeError> {
        if !keys::is_plain_chunk(recorder) {
            return Err(BridgeError::InvalidArgument(format!(
                "recorder name `{recorder}` must be non-empty and made of letters, digits, \
                 `-`, `_`, `.`"
            )));
        }
        let publisher = zsession
            .declare_publisher(keys::episodes(task_name(task)?, recorder))
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(BridgeError::zenoh("declaring the episode publisher"))?;
        Ok(Self {
            publisher,
            recorder: recorder.to_owned(),
        })
    }

    pub fn key(&self) -> &str {
        self.publisher.key_expr().as_str()
    }

    /// Publishes episode number `index` of the dataset `spec`.
    pub fn publish(
        &self,
        index: u64,
        spec: &DatasetSpec,
        episode: &Episode,
    ) -> Result<(), BridgeError> {
        let message = EpisodeMsg::from_dataset(&self.recorder, index, spec, episode);
        self.publisher
            .put(encode(&message))
            .wait()
            .map_err(BridgeError::zenoh("publishing an episode"))
    }
}

/// Why collecting episodes failed.
#[derive(Debug, thiserror::Error)]
pub enum CollectError {
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    #[error(
        "{received} of {expected} episodes of `{task}` arrived on `{key}`, then none for \
         {waited:?}. A recorder must be running on the same Zenoh network and publishing, \
         e.g. `python -m ciflow.record --task {task} --episodes {expected} --out <dir>` \
         (both connect to the engine on tcp/127.0.0.1:7447 by default, or to the same router)"
    )]
    Timeout {
        task: String,
        key: String,
        received: usize,
        expected: usize,
        waited: Duration,
    },
    #[error("undecodable episode on `{key}`: {source}")]
    Undecodable { key: String, source: EpisodeError },
    #[error(
        "episode {index} of recorder `{recorder}` does not fit the episodes before it: {detail}"
    )]
    Mismatch {
        recorder: String,
        index: u64,
        detail: String,
    },
}

/// A subscription to every recorder's episodes of one task.
pub struct EpisodeSubscriber {
    subscriber: Subscriber<FifoChannelHandler<Sample>>,
    task: &'static str,
}

impl EpisodeSubscriber {
    /// Subscribes to the episodes of `task` (name or Gymnasium id). Episodes published
    /// from now on are queued until [`EpisodeSubscriber::collect`] takes them.
    pub fn declare(zsession: &zenoh::Session, task: &str) -> Result<Self, BridgeError> {
        let task = task_name(task)?;
        let subscriber = zsession
            .declare_subscriber(keys::all_episodes(task))
            .wait()
            .map_err(BridgeError::zenoh("subscribing to the episodes"))?;
        Ok(Self { subscriber, task })
    }

    /// The key expression it listens on.
    pub fn key(&self) -> &str {
        self.subscriber.key_expr().as_str()
    }

    /// Waits for `count` episodes, at most `timeout` for each, calling `on_episode` as
    /// each arrives. All must share the first one's task, spaces and period; they come
    /// back ordered by (recorder, index), with the first episode's dataset description.
    pub fn collect(
        &self,
        count: usize,
        timeout: Duration,
        mut on_episode: impl FnMut(&EpisodeMsg),
    ) -> Result<(DatasetSpec, Vec<Episode>), CollectError> {
        let mut spec: Option<DatasetSpec> = None;
        let mut received: Vec<(String, u64, Episode)> = Vec::with_capacity(count);
        while received.len() < count {
            let started = Instant::now();
            let sample = match self.subscriber.recv_timeout(timeout) {
                Ok(Some(sample)) => sample,
                Ok(None) | Err(_) => {
                    return Err(CollectError::Timeout {
                        task: self.task.to_owned(),
                        key: self.key().to_owned(),
                        received: received.len(),
                        expected: count,
                        waited: started.elapsed(),
                    });
                }
            };
            let key = sample.key_expr().as_str().to_owned();
            let undecodable = |source| CollectError::Undecodable {
                key: key.clone(),
                source,
            };
            let message = decode_episode(&sample.payload().to_bytes()).map_err(undecodable)?;
            on_episode(&message);
            let (recorder, index) = (message.recorder.clone(), message.index);
            let (episode_spec, episode) = message.into_dataset().map_err(undecodable)?;
            match &spec {
                None => spec = Some(episode_spec),
                Some(first) => {
                    if let Some(detail) = mismatch(first, &episode_spec) {
                        return Err(CollectError::Mismatch {
                            recorder,
                            index,
                            detail,
                        });
                    }
                }
            }
            received.push((recorder, index, episode));
        }
        received.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        let spec = spec.expect("count > 0 episodes were received");
        Ok((spec, received.into_iter().map(|(_, _, e)| e).collect()))
    }
}

/// What makes `other` unfit to share a dataset with `first` (the dataset id may differ).
fn mismatch(first: &DatasetSpec, other: &DatasetSpec) -> Option<String> {
    if other.env_id != first.env_id {
        return Some(format!("task {} instead of {}", other.env_id, first.env_id));
    }
    if other.env_kwargs != first.env_kwargs {
        return Some(format!(
            "construction arguments {:?} instead of {:?}",
            other.env_kwargs, first.env_kwargs
        ));
    }
    let spaces = [
        (
            "observation",
            &first.observation_space,
            &other.observation_space,
        ),
        ("action", &first.action_space, &other.action_space),
        ("context", &first.context_space, &other.context_space),
    ];
    for (name, a, b) in spaces {
        if a != b {
            return Some(format!(
                "{name} space of dimension {} differs from the first episode's ({})",
                b.dim(),
                a.dim()
            ));
        }
    }
    (other.control_dt != first.control_dt).then(|| {
        format!(
            "control_dt {} s instead of {} s",
            other.control_dt, first.control_dt
        )
    })
}

/// Joins Zenoh as a client (default: the engine on [`crate::DEFAULT_ENDPOINT`], through
/// which recorders publish) and collects `count` episodes of `task`; `on_subscribed` runs
/// once the subscription is in place (recorders may start then), `on_episode` per episode.
pub fn collect(
    network: &NetworkOptions,
    task: &str,
    count: usize,
    timeout: Duration,
    on_subscribed: impl FnOnce(&str),
    on_episode: impl FnMut(&EpisodeMsg),
) -> Result<(DatasetSpec, Vec<Episode>), CollectError> {
    if count == 0 {
        return Err(BridgeError::InvalidArgument("collect at least one episode".into()).into());
    }
    let zsession = network.open(
        Role::Client,
        "join Zenoh",
        "episodes travel through an engine or a router: start one with `ciflow serve`, or \
         point --connect/--config at a router",
    )?;
    let subscriber = EpisodeSubscriber::declare(&zsession, task)?;
    on_subscribed(subscriber.key());
    subscriber.collect(count, timeout, on_episode)
}

#[cfg(test)]
mod tests {
    use ciflow_envs::ResetOptions;
    use ciflow_envs::rollout::{expert_dataset_spec, expert_episode};

    use super::*;

    /// A hub peer on a private port and two clients of it: recorder and trainer meet
    /// through the hub, as they meet through `ciflow serve`.
    fn sessions(port: u16) -> (zenoh::Session, zenoh::Session, zenoh::Session) {
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let open = |role| {
            let config = NetworkOptions::endpoint(role, &endpoint)
                .to_zenoh_config(role)
                .unwrap();
            zenoh::open(config).wait().unwrap()
        };
        let hub = open(Role::Engine);
        (hub, open(Role::Client), open(Role::Client))
    }

    #[test]
    fn episodes_travel_from_a_recorder_to_a_trainer_through_a_hub() {
        let (_hub, recorder, trainer) = sessions(27461);
        let mut env = ciflow_envs::make("limit-cycle").unwrap();
        let spec = expert_dataset_spec(
            env.as_ref(),
            &Default::default(),
            "ciflow/limit-cycle-expert-v0",
        );
        let episodes: Vec<Episode> = (0..3)
            .map(|seed| expert_episode(env.as_mut(), Some(seed), &ResetOptions::default()))
            .collect::<Result<_, _>>()
            .unwrap();

        let subscriber = EpisodeSubscriber::declare(&trainer, "ciflow/LimitCycle-v0").unwrap();
        assert_eq!(subscriber.key(), "ciflow/v2/episodes/limit-cycle/*");
        let publisher = EpisodePublisher::declare(&recorder, "limit-cycle", "rec-a").unwrap();
        assert_eq!(publisher.key(), "ciflow/v2/episodes/limit-cycle/rec-a");
        std::thread::sleep(Duration::from_millis(300));
        for (index, episode) in episodes.iter().enumerate() {
            publisher.publish(index as u64, &spec, episode).unwrap();
        }
        let mut seen = Vec::new();
        let (got_spec, got) = subscriber
            .collect(3, Duration::from_secs(10), |m| seen.push(m.index))
            .unwrap();
        assert_eq!(seen, [0, 1, 2]);
        assert_eq!(got_spec, spec);
        assert_eq!(got, episodes);

        match subscriber.collect(1, Duration::from_millis(200), |_| {}) {
            Err(CollectError::Timeout {
                received: 0,
                expected: 1,
                ..
            }) => {}
            other => panic!("expected a timeout, got {other:?}"),
        }
        assert!(EpisodePublisher::declare(&recorder, "limit-cycle", "a/b").is_err());
        assert!(EpisodeSubscriber::declare(&trainer, "no-such-task").is_err());
    }

    #[test]
    fn foreign_payloads_and_mismatched_episodes_are_errors() {
        let (_hub, recorder, trainer) = sessions(27462);
        let subscriber = EpisodeSubscriber::declare(&trainer, "obstacle-avoidance").unwrap();
        std::thread::sleep(Duration::from_millis(300));
        recorder
            .put(
                keys::episodes("obstacle-avoidance", "junk"),
                b"\x01\x02".to_vec(),
            )
            .wait()
            .unwrap();
        assert!(matches!(
            subscriber.collect(1, Duration::from_secs(10), |_| {}),
            Err(CollectError::Undecodable { .. })
        ));

        let publisher =
            EpisodePublisher::declare(&recorder, "obstacle-avoidance", "rec-b").unwrap();
        for obstacles in [1.0, 3.0] {
            let kwargs = [("obstacles".to_owned(), obstacles.into())].into();
            let mut env = ciflow_envs::make_with("obstacle-avoidance", &kwargs).unwrap();
            let spec =
                expert_dataset_spec(env.as_ref(), &kwargs, "ciflow/obstacle-avoidance-expert-v0");
            let episode = expert_episode(env.as_mut(), Some(0), &ResetOptions::default()).unwrap();
            publisher.publish(0, &spec, &episode).unwrap();
        }
        assert!(matches!(
            subscriber.collect(2, Duration::from_secs(10), |_| {}),
            Err(CollectError::Mismatch { .. })
        ));
    }
}
