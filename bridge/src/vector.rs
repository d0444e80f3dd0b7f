//! One vector environment over sessions on several engines: environment `i` of the batch
//! lives in the session whose share holds it, in the sessions' order. Each call sends
//! every session its share before it takes any reply, so the engines step at the same time
//! and a step costs the slowest engine's round trip, with no thread per engine; the replies
//! are merged in the sessions' order, so results do not depend on which engine answers
//! first. A failure names its engine.

use std::collections::BTreeSet;

use ciflow_envs::ResetOptions;

use crate::client::{BatchStep, BatchStepOut, InfoColumns, RemoteEnv};
use crate::error::BridgeError;
use crate::protocol::BatchSeeds;
use crate::query::Pending;

/// Resets every environment of `sessions`; environment `i` of the batch gets its seed of
/// `seeds` ([`BatchSeeds::of`]), and the options' row `i` where they give one row per
/// environment ([`ResetOptions::rows`]). Returns the observations (row-major) and the
/// info columns, merged.
pub fn reset_batches(
    sessions: &[&RemoteEnv],
    seeds: impl Into<BatchSeeds>,
    options: Option<ResetOptions>,
) -> Result<(Vec<f64>, InfoColumns), BridgeError> {
    let shape = batch_shape(sessions)?;
    let seeds = seeds.into();
    if let Some(count) = seeds.count().filter(|&count| count != shape.envs) {
        return Err(BridgeError::InvalidArgument(format!(
            "{count} seeds for {} environments",
            shape.envs
        )));
    }
    if let (Some(options), Some(session)) = (&options, sessions.first()) {
        // Checked against the whole batch: each engine sees only its share.
        options
            .check_rows(shape.envs, session.spec())
            .map_err(|error| BridgeError::InvalidArgument(error.to_string()))?;
    }
    let mut offset = 0;
    let replies = in_flight(sessions, |session| {
        let share = offset..offset + session.num_envs() as usize;
        let session_seeds = seeds.share(share.clone());
        let session_options = options
            .as_ref()
            .map(|o| o.rows(shape.envs, share.clone(), session.spec()));
        offset = share.end;
        session.send_reset_batch(session_seeds, session_options)
    })?;
    let mut observations = Vec::with_capacity(shape.envs * shape.observation_dim);
    let mut infos = Vec::with_capacity(sessions.len());
    for (session, pending) in sessions.iter().zip(replies) {
        let (part, info) = RemoteEnv::reset_reply(pending).map_err(in_engine(session))?;
        observations.extend(part);
        infos.push(info);
    }
    Ok((observations, merge_columns(sessions, infos)))
}

/// Steps every environment of `sessions` with row-major `actions` (`Σ num_envs ×
/// action_dim`), next-step autoreset as [`RemoteEnv::step_batch`]; the replies merged.
pub fn step_batches(sessions: &[&RemoteEnv], actions: &[f64]) -> Result<BatchStep, BridgeError> {
    let shape = batch_shape(sessions)?;
    BatchStep::written(shape.envs, shape.observation_dim, |out| {
        step_batches_into(sessions, actions, out)
    })
}

/// [`step_batches`] with the merged observations, rewards and flags written into `out`
/// (sized for every environment of `sessions`), each reply copied there once from its
/// payload; returns the merged info columns.
pub fn step_batches_into(
    sessions: &[&RemoteEnv],
    actions: &[f64],
    mut out: BatchStepOut<'_>,
) -> Result<InfoColumns, BridgeError> {
    let BatchShape {
        envs,
        action_dim,
        observation_dim,
    } = batch_shape(sessions)?;
    if actions.len() != envs * action_dim {
        return Err(BridgeError::InvalidArgument(format!(
            "{} action values for {envs} environments of {action_dim} each",
            actions.len()
        )));
    }
    if out.envs(observation_dim) != Some(envs) {
        return Err(BridgeError::InvalidArgument(format!(
            "result buffers of {} observation, {} reward, {} and {} flag bytes for {envs} \
             environments of {observation_dim} observations",
            out.observations.len(),
            out.rewards.len(),
            out.terminated.len(),
            out.truncated.len()
        )));
    }
    let mut rest = actions;
    let replies = in_flight(sessions, |session| {
        let (share, after) = rest.split_at(session.num_envs() as usize * action_dim);
        rest = after;
        session.send_step_batch(share)
    })?;
    let mut infos = Vec::with_capacity(sessions.len());
    let mut first = 0;
    for (session, pending) in sessions.iter().zip(replies) {
        let rows = first..first + session.num_envs() as usize;
        first = rows.end;
        let mut share = out.rows(rows, observation_dim);
        infos.push(
            session
                .step_reply_into(pending, &mut share)
                .map_err(in_engine(session))?,
        );
    }
    Ok(merge_columns(sessions, infos))
}

/// A batch's size and spaces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BatchShape {
    /// Environments of all the sessions.
    pub envs: usize,
    pub action_dim: usize,
    pub observation_dim: usize,
}

/// The shape of the batch of `sessions`: at least one session, all of the same spaces
/// (what [`step_batches_into`]'s buffers are sized by).
pub fn batch_shape(sessions: &[&RemoteEnv]) -> Result<BatchShape, BridgeError> {
    let Some(first) = sessions.first() else {
        return Err(BridgeError::InvalidArgument(
            "a vector environment needs at least one session".into(),
        ));
    };
    let spaces = |s: &RemoteEnv| {
        let spec = s.spec();
        (spec.action_space.dim(), spec.observation_space.dim())
    };
    if let Some(other) = sessions.iter().find(|s| spaces(s) != spaces(first)) {
        return Err(BridgeError::InvalidArgument(format!(
            "sessions on `{}` and `{}` have different spaces: {:?} and {:?} (action, \
             observation dimensions)",
            first.engine(),
            other.engine(),
            spaces(first),
            spaces(other)
        )));
    }
    let (action_dim, observation_dim) = spaces(first);
    Ok(BatchShape {
        envs: sessions.iter().map(|s| s.num_envs() as usize).sum(),
        action_dim,
        observation_dim,
    })
}

/// `send(session)` for every session, in order: all the queries in flight before any
/// reply is taken.
fn in_flight<'a>(
    sessions: &[&'a RemoteEnv],
    mut send: impl FnMut(&'a RemoteEnv) -> Result<Pending<'a>, BridgeError>,
) -> Result<Vec<Pending<'a>>, BridgeError> {
    sessions
        .iter()
        .map(|session| send(session).map_err(in_engine(session)))
        .collect()
}

/// The sessions' info columns as one: a key some session did not report is NaN (absent)
/// for its environments.
fn merge_columns(sessions: &[&RemoteEnv], mut parts: Vec<InfoColumns>) -> InfoColumns {
    if parts.len() == 1 {
        return parts.pop().unwrap_or_default();
    }
    let keys: BTreeSet<String> = parts
        .iter()
        .flat_map(|columns| columns.keys().cloned())
        .collect();
    let envs = sessions.iter().map(|s| s.num_envs() as usize).sum();
    keys.into_iter()
        .map(|key| {
            let mut values = Vec::with_capacity(envs);
            for (session, columns) in sessions.iter().zip(&mut parts) {
                match columns.remove(&key) {
                    Some(part) => values.extend(part),
                    None => values.resize(values.len() + session.num_envs() as usize, f64::NAN),
                }
            }
            (key, values)
        })
        .collect()
}

/// Names `session`'s engine in its error.
fn in_engine(session: &RemoteEnv) -> impl Fn(BridgeError) -> BridgeError + '_ {
    move |source| BridgeError::Engine {
        engine: session.engine().to_owned(),
        source: Box::new(source),
    }
}
