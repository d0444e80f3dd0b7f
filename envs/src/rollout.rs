//! Recording episodes of the expert: what `ciflow demos` and the tests run.

use crate::dataset::{Credits, DatasetFormat, DatasetSpec, Episode};
use crate::env::{Env, EnvError, ResetOptions};
use crate::registry::{Kwarg, Kwargs};

/// Resets `env` with `seed` and `options`, then lets the expert act until the episode
/// terminates or is truncated, recording everything a dataset holds.
pub fn expert_episode(
    env: &mut dyn Env,
    seed: Option<u64>,
    options: &ResetOptions,
) -> Result<Episode, EnvError> {
    let context_dim = env.spec().context_space.dim();
    let context_of = |observation: &[f64]| observation[observation.len() - context_dim..].to_vec();
    let (observation, info) = env.reset(seed, options)?;
    let mut episode = Episode {
        seed,
        contexts: vec![context_of(&observation)],
        observations: vec![observation],
        infos: info
            .into_iter()
            .map(|(k, v)| (k.into_owned(), vec![v]))
            .collect(),
        ..Episode::default()
    };
    loop {
        let action = env.expert_action()?;
        let step = env.step(&action)?;
        episode.actions.push(action);
        episode.contexts.push(context_of(&step.observation));
        episode.observations.push(step.observation);
        episode.rewards.push(step.reward);
        episode.terminations.push(step.terminated);
        episode.truncations.push(step.truncated);
        for (key, value) in step.info {
            episode
                .infos
                .entry(key.into_owned())
                .or_default()
                .push(value);
        }
        if step.terminated || step.truncated {
            return Ok(episode);
        }
    }
}

/// The dataset description of the expert demonstrations of `env`, built with `kwargs`.
pub fn expert_dataset_spec(env: &dyn Env, kwargs: &Kwargs, dataset_id: &str) -> DatasetSpec {
    let spec = env.spec();
    DatasetSpec {
        dataset_id: dataset_id.to_string(),
        env_id: spec.id.clone(),
        env_kwargs: kwargs.clone(),
        observation_space: spec.observation_space.clone(),
        action_space: spec.action_space.clone(),
        context_space: spec.context_space.clone(),
        control_dt: spec.control_dt,
        algorithm_name: "expert".into(),
        credits: Credits::default(),
    }
}

/// What [`record_expert_dataset`] records.
#[derive(Clone, Debug, PartialEq)]
pub struct Recording {
    /// Task name or Gymnasium id.
    pub task: String,
    /// Construction arguments of the task.
    pub kwargs: Kwargs,
    /// Reset options for every episode (`ResetOptions::extra`).
    pub options: std::collections::BTreeMap<String, f64>,
    pub episodes: u64,
    /// Episode `i` is reset with seed `seed + i`.
    pub seed: u64,
    /// Minari dataset id; `ciflow/<task name>-expert-v0` when unset.
    pub dataset_id: Option<String>,
    /// Who made the dataset.
    pub credits: Credits,
    /// The layout to write.
    pub format: DatasetFormat,
}

/// Why a recording failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("episode {episode}: {source}")]
    Env { episode: u64, source: EnvError },
    #[error(transparent)]
    Make(#[from] EnvError),
    #[error(transparent)]
    Dataset(#[from] crate::dataset::DatasetError),
    #[error(
        "{episodes} episodes from seed {seed}: give at least one episode, and a first seed \
         at most 2^64 - 1 - episodes (episode i is reset with seed + i, which must not wrap)"
    )]
    Seeds { episodes: u64, seed: u64 },
    #[error(
        "`{key}` is given as a construction argument ({kwarg}) and as a reset option \
         ({option}): the dataset would be labelled with the first and hold the second; give \
         it once"
    )]
    Conflict {
        key: String,
        kwarg: String,
        option: f64,
    },
}

/// Refuses reset `options` that change what a construction argument of the same name in
/// `kwargs` chose (LASA's and obstacle avoidance's options share their arguments' names):
/// a dataset's metadata carry the construction arguments only, so its episodes would hold
/// one thing and be labelled with another. Every recorder checks this.
pub fn check_options_keep_kwargs(
    kwargs: &Kwargs,
    options: &std::collections::BTreeMap<String, f64>,
) -> Result<(), RecordingError> {
    match options.iter().find_map(|(key, option)| {
        let kwarg = kwargs.get(key)?;
        (*kwarg != Kwarg::Number(*option)).then_some((key, *option, kwarg))
    }) {
        Some((key, option, kwarg)) => Err(RecordingError::Conflict {
            key: key.clone(),
            kwarg: kwarg.to_string(),
            option,
        }),
        None => Ok(()),
    }
}

/// Records expert episodes into a dataset at `out`, atomically, in `recording.format`;
/// `on_episode` is called after each episode (for progress bars). Returns the dataset's
/// description.
pub fn record_expert_dataset(
    recording: &Recording,
    out: &std::path::Path,
    overwrite: bool,
    mut on_episode: impl FnMut(&Episode),
) -> Result<DatasetSpec, RecordingError> {
    crate::dataset::check_replaceable(out, overwrite)?;
    let (episodes, seed) = (recording.episodes, recording.seed);
    if episodes == 0 || seed.checked_add(episodes - 1).is_none() {
        return Err(RecordingError::Seeds { episodes, seed });
    }
    check_options_keep_kwargs(&recording.kwargs, &recording.options)?;
    let entry = crate::registry::entry(&recording.task)?;
    let mut env = (entry.make_with)(&recording.kwargs)?;
    let dataset_id = recording
        .dataset_id
        .clone()
        .unwrap_or_else(|| format!("ciflow/{}-expert-v0", entry.name));
    let spec = DatasetSpec {
        credits: recording.credits.clone(),
        ..expert_dataset_spec(env.as_ref(), &recording.kwargs, &dataset_id)
    };
    let options = ResetOptions {
        extra: recording.options.clone(),
        ..ResetOptions::default()
    };
    // LeRobot is written from the Minari layout, recorded beside the target first.
    let minari = match recording.format {
        DatasetFormat::Minari => out.to_path_buf(),
        DatasetFormat::Lerobot => out.with_file_name(format!(
            ".{}.minari-{}",
            out.file_name().unwrap_or_default().to_string_lossy(),
            std::process::id()
        )),
    };
    let mut writer = crate::dataset::DatasetWriter::create(&minari, spec, true)?;
    let spec = writer.spec().clone();
    for episode in 0..recording.episodes {
        let seed = recording.seed + episode;
        let data = expert_episode(env.as_mut(), Some(seed), &options)
            .map_err(|source| RecordingError::Env { episode, source })?;
        writer.append(&data)?;
        on_episode(&data);
    }
    writer.finish()?;
    if recording.format == DatasetFormat::Lerobot {
        let written = crate::dataset::write_lerobot(&minari, out, overwrite);
        // Best effort: a leftover hidden directory is harmless, just untidy.
        let _ = std::fs::remove_dir_all(&minari);
        written?;
    }
    Ok(spec)
}
