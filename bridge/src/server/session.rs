//! A session: `num_envs` environments of one task, owned by one client, guarded by a
//! secret token. Each method implements one operation and returns the encoded reply.

use std::borrow::Cow;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};

use ciflow_engine::sim::{Perturbation, PerturbationKind};
use ciflow_envs::registry::Kwargs;
use ciflow_envs::{EnvError, EnvSpec, Info, ResetOptions};
use rayon::prelude::*;
use serde_bytes::ByteBuf;
use zenoh::bytes::ZBytes;

use super::reply_memory::ReplyMemory;
use super::reported_contexts::ReportedContexts;
use super::slot::{EnvSlot, check_vector};
use super::telemetry::TelemetryPublisher;
use crate::error::full_message;
use crate::policy::Policy;
use crate::protocol::{
    AckReply, ActionReply, BatchResetReply, BatchSeeds, BatchStepWriter, ContextCheckReply,
    ContextRequest, DescribeReply, ErrorCode, ErrorReply, F64s, FrameHeader, InfoBlock,
    MessageBuffer, PROTOCOL_VERSION, PerturbRequest, PerturbationKindMsg, ResetReply, ResetRequest,
    RunRequest, StepReply, TOKEN_BYTES, context_update_len, encode,
};

/// Environments per rayon task in `step_batch`: below this, threads cost more than they
/// save.
const BATCH_CHUNK: usize = 512;

pub(crate) type Token = [u8; TOKEN_BYTES];

pub(crate) struct Session {
    pub id: String,
    pub owner: String,
    token: Token,
    spec: EnvSpec,
    /// The construction arguments the session was made with (for `describe`).
    kwargs: Kwargs,
    envs: Vec<EnvSlot>,
    /// Options of the last reset, reused by autoresets.
    reset_options: AutoresetOptions,
    telemetry: TelemetryPublisher,
    frames: u64,
    /// The policy run driving the session, if any (see [`super::driver`]), and its place
    /// among the engine's runs, given back the moment the run ends.
    run: Option<(Run, RunPermit)>,
    /// Runs started so far: each run's id, so a stopped driver never steps a later run.
    runs: u64,
    /// Room for the info columns of a `step_batch` reply (their keys and headers
    /// included): the most they took so far, at least the estimate the last batch reset's
    /// keys give before the first step. A context update has room of its own
    /// ([`ReportedContexts::room`]).
    info_bytes: usize,
    /// The contexts `step_batch` replies have reported, for clients that keep a copy.
    reported_contexts: ReportedContexts,
    /// Environments whose episode ended at the last `step_batch`: they autoreset at the
    /// next.
    autoresets: usize,
}

/// One of the engine's `max_runs` places for a running policy, held by the session while
/// the run lasts; freed when dropped.
pub(crate) struct RunPermit(Arc<AtomicU32>);

impl RunPermit {
    /// A place, unless `max` runs hold one already.
    pub fn take(running: &Arc<AtomicU32>, max: u32) -> Option<Self> {
        running
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < max).then_some(n + 1)
            })
            .ok()
            .map(|_| Self(Arc::clone(running)))
    }
}

impl Drop for RunPermit {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// A policy driving one environment of the session.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Run {
    pub id: u64,
    pub index: usize,
    pub policy: String,
}

/// The options autoresets reset with: the last reset's, one set for every environment
/// or, where it gave one row per environment ([`ResetOptions::rows`]), a set each.
enum AutoresetOptions {
    Shared(ResetOptions),
    PerEnvironment(Vec<ResetOptions>),
}

impl AutoresetOptions {
    fn new(options: ResetOptions, n: usize, spec: &EnvSpec) -> Self {
        if options.has_rows(n, spec) {
            Self::PerEnvironment((0..n).map(|i| options.rows(n, i..i + 1, spec)).collect())
        } else {
            Self::Shared(options)
        }
    }

    /// Environment `i`'s.
    fn of(&self, i: usize) -> &ResetOptions {
        match self {
            Self::Shared(options) => options,
            Self::PerEnvironment(options) => &options[i],
        }
    }
}

impl Session {
    pub fn new(
        id: String,
        owner: String,
        token: Token,
        kwargs: Kwargs,
        envs: Vec<EnvSlot>,
        telemetry: TelemetryPublisher,
    ) -> Self {
        let spec = envs[0].env.spec().clone();
        let reported_contexts = ReportedContexts::new(envs.len(), spec.context_space.dim());
        Self {
            id,
            owner,
            token,
            spec,
            kwargs,
            envs,
            reset_options: AutoresetOptions::Shared(ResetOptions::default()),
            telemetry,
            frames: 0,
            run: None,
            runs: 0,
            info_bytes: 0,
            reported_contexts,
            autoresets: 0,
        }
    }

    /// What the session is: its task, construction arguments and size.
    pub fn describe(&self) -> Vec<u8> {
        encode(&DescribeReply {
            v: PROTOCOL_VERSION,
            task: self.spec.id.clone(),
            kwargs: self.kwargs.clone(),
            num_envs: self.envs.len() as u32,
        })
    }

    /// Refuses callers that do not hold the session's token.
    pub fn authorize(&self, token: &ByteBuf) -> Result<(), ErrorReply> {
        // Compare every byte so the time taken does not reveal the matching prefix.
        let equal = token.len() == TOKEN_BYTES
            && token
                .iter()
                .zip(&self.token)
                .fold(0u8, |acc, (a, b)| acc | (a ^ b))
                == 0;
        if equal {
            Ok(())
        } else {
            Err(ErrorReply::new(
                ErrorCode::Forbidden,
                format!("wrong or missing token for session {}", self.id),
            ))
        }
    }

    /// Refuses client-driven stepping while a policy drives the session.
    pub fn ensure_idle(&self, op: &str) -> Result<(), ErrorReply> {
        match &self.run {
            None => Ok(()),
            Some((run, _)) => Err(ErrorReply::new(
                ErrorCode::Busy,
                format!(
                    "`{op}` refused: policy `{}` drives session {}; send `stop` first",
                    run.policy, self.id
                ),
            )),
        }
    }

    /// Starts a run of `policy` (already looked up under `request.policy`) holding
    /// `permit`; the caller hands its driver to a scheduler.
    pub fn start_run(
        &mut self,
        request: &RunRequest,
        policy: &dyn Policy,
        permit: RunPermit,
    ) -> Result<Run, ErrorReply> {
        self.ensure_idle("run")?;
        if !(request.speed.is_finite() && request.speed >= 0.0) {
            return Err(ErrorReply::new(
                ErrorCode::OutOfBounds,
                format!("speed {} must be finite and ≥ 0", request.speed),
            ));
        }
        let info = policy.info();
        let (observation_dim, action_dim) = (self.observation_dim(), self.spec.action_space.dim());
        if info.observation_dim as usize != observation_dim
            || info.action_dim as usize != action_dim
        {
            return Err(ErrorReply::new(
                ErrorCode::WrongDimension,
                format!(
                    "policy `{}` maps {} observations to {} actions; this session has {} and {}",
                    info.name, info.observation_dim, info.action_dim, observation_dim, action_dim
                ),
            ));
        }
        let slot = self.slot(request.index)?;
        if slot.needs_reset() {
            return Err(EnvError::NeedsReset.into());
        }
        self.runs += 1;
        let run = Run {
            id: self.runs,
            index: request.index as usize,
            policy: request.policy.clone(),
        };
        self.run = Some((run.clone(), permit));
        Ok(run)
    }

    /// Whether `run` still drives the session (not stopped, not replaced).
    pub fn is_running(&self, run: &Run) -> bool {
        self.run
            .as_ref()
            .is_some_and(|(current, _)| current.id == run.id)
    }

    /// One control period of `run` with the action `policy` takes in the current
    /// observation. Returns whether the run goes on; `last` ends it after this step.
    pub fn drive(
        &mut self,
        run: &Run,
        policy: &dyn Policy,
        action: &mut [f64],
        last: bool,
    ) -> Result<bool, ErrorReply> {
        let slot = &mut self.envs[run.index];
        // What a driven run reports is the slot's (telemetry), not the step's info.
        let mut info = Info::new();
        let outcome = policy
            .act_into(&slot.observation, action)
            .map_err(|e| ErrorReply::new(ErrorCode::Policy, full_message(&e)))
            .and_then(|()| slot.step(action, &mut info).map_err(ErrorReply::from));
        let going_on = matches!(&outcome, Ok(step) if !(step.terminated || step.truncated || last));
        if !going_on {
            self.run = None;
        }
        self.telemetry
            .offer_run(&self.id, &self.envs[run.index], going_on);
        outcome.map(|_| going_on)
    }

    /// Stops the run, if any; returns the simulated time of the driven environment.
    pub fn stop_run(&mut self) -> Result<Vec<u8>, ErrorReply> {
        let index = self.run.take().map_or(0, |(run, _)| run.index);
        self.telemetry.offer_run(&self.id, &self.envs[index], false);
        Ok(encode(&AckReply {
            v: PROTOCOL_VERSION,
            time: self.envs[index].time(),
        }))
    }

    pub fn num_envs(&self) -> u32 {
        self.envs.len() as u32
    }

    /// Seconds of simulated time per step.
    pub fn control_dt(&self) -> f64 {
        self.spec.control_dt
    }

    fn single(&mut self, op: &str) -> Result<&mut EnvSlot, ErrorReply> {
        if self.envs.len() != 1 {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!(
                    "`{op}` needs a single-environment session; session {} has {} \
                     environments (use `{op}_batch`)",
                    self.id,
                    self.envs.len()
                ),
            ));
        }
        Ok(&mut self.envs[0])
    }

    fn slot(&mut self, index: u32) -> Result<&mut EnvSlot, ErrorReply> {
        let n = self.envs.len();
        self.envs.get_mut(index as usize).ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!("environment index {index} out of range (session has {n})"),
            )
        })
    }

    pub fn reset(&mut self, request: ResetRequest) -> Result<Vec<u8>, ErrorReply> {
        if request.seeds.is_some() {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                "`seeds` is for `reset_batch`; `reset` takes one `seed`",
            ));
        }
        let options = request.options.unwrap_or_default();
        let slot = self.single("reset")?;
        let (observation, info) = slot.reset(request.seed, &options)?;
        self.reset_options = AutoresetOptions::Shared(options);
        self.telemetry.offer(&self.id, &self.envs[0]);
        Ok(encode(&ResetReply {
            v: PROTOCOL_VERSION,
            observation: F64s(observation),
            info,
        }))
    }

    pub fn step(&mut self, action: &[f64]) -> Result<Vec<u8>, ErrorReply> {
        let slot = self.single("step")?;
        let mut info = Info::new();
        let step = slot.step(action, &mut info)?;
        let time = slot.time();
        let observation = slot.observation.clone();
        self.telemetry.offer(&self.id, &self.envs[0]);
        Ok(encode(&StepReply {
            v: PROTOCOL_VERSION,
            observation: F64s(observation),
            reward: step.reward,
            terminated: step.terminated,
            truncated: step.truncated,
            info,
            time,
        }))
    }

    pub fn reset_batch(&mut self, request: ResetRequest) -> Result<Vec<u8>, ErrorReply> {
        let n = self.envs.len();
        let seeds = BatchSeeds::of_request(request.seed, request.seeds).ok_or_else(|| {
            ErrorReply::new(
                ErrorCode::InvalidRequest,
                "give `seed` or `seeds`, not both",
            )
        })?;
        if let Some(count) = seeds.count().filter(|&count| count != n) {
            return Err(ErrorReply::new(
                ErrorCode::InvalidRequest,
                format!("{count} seeds for {n} environments"),
            ));
        }
        let options = request.options.unwrap_or_default();
        options.check_rows(n, &self.spec)?;
        let options = AutoresetOptions::new(options, n, &self.spec);
        let results: Vec<Result<(Vec<f64>, Info), EnvError>> = self
            .envs
            .par_iter_mut()
            .with_min_len(BATCH_CHUNK)
            .enumerate()
            .map(|(i, slot)| slot.reset(seeds.of(i), options.of(i)))
            .collect();
        let mut observations = Vec::with_capacity(self.envs.len() * self.observation_dim());
        let mut infos = Vec::with_capacity(results.len());
        for (i, result) in results.into_iter().enumerate() {
            let (observation, info) = result.map_err(|e| in_env(i, e))?;
            observations.extend_from_slice(&observation);
            infos.push(info);
        }
        self.reset_options = options;
        self.telemetry.offer(&self.id, &self.envs[0]);
        let info = InfoColumns::from_infos(&infos);
        // Tasks report again at each step what they report at a reset, most of them: room
        // for those columns, with a key of up to 64 bytes each, lets the first step's
        // reply be written in place too.
        self.info_bytes = self.info_bytes.max(info.columns.len() * (8 * n + 64));
        self.reported_contexts.requested(n);
        self.autoresets = 0;
        Ok(encode(&BatchResetReply {
            v: PROTOCOL_VERSION,
            observations: F64s(observations),
            info: info.into_map(),
        }))
    }

    /// Steps every environment (next-step autoreset) and encodes the reply in `memory`.
    /// For a client that holds the contexts of reply `known_contexts`, the rows leave
    /// their contexts out and the reply ends with those that changed since.
    pub fn step_batch(
        &mut self,
        actions: &[f64],
        known_contexts: Option<u64>,
        memory: &ReplyMemory,
    ) -> Result<ZBytes, ErrorReply> {
        let n = self.envs.len();
        let (action_dim, observation_dim) = (self.spec.action_space.dim(), self.observation_dim());
        check_vector("actions", actions, n * action_dim)?;
        let state_dim = observation_dim - self.spec.context_space.dim();
        let options = &self.reset_options;
        // Room for the info columns, so that appending them does not move the rows.
        let allocate = |len| memory.buffer(len);
        let (mut reply, reported, row_dim) = match known_contexts {
            Some(known) => (
                BatchStepWriter::with_contexts_in(
                    allocate,
                    n,
                    state_dim,
                    self.info_bytes + self.reported_contexts.room(known, self.autoresets),
                ),
                self.reported_contexts.start(known, BATCH_CHUNK)?,
                state_dim,
            ),
            None => {
                // The autoresets change contexts that no update reports at this step: the
                // next update must have room for them.
                self.reported_contexts.requested(self.autoresets);
                (
                    BatchStepWriter::new_in(allocate, n, observation_dim, self.info_bytes),
                    Vec::new(),
                    observation_dim,
                )
            }
        };
        let info_offset = reply.info_offset();
        // Each rayon task steps a chunk and writes its rows into the reply: no
        // per-environment work is left to this thread.
        let mut reported = reported.into_iter();
        let chunks: Vec<_> = self
            .envs
            .chunks_mut(BATCH_CHUNK)
            .zip(actions.chunks((BATCH_CHUNK * action_dim).max(1)))
            .zip(reply.rows().blocks(BATCH_CHUNK))
            .map(|chunk| (chunk, reported.next()))
            .collect();
        drop(reported);
        let chunks: Vec<Result<(InfoColumns, usize), ErrorReply>> = chunks
            .into_par_iter()
            .enumerate()
            .map(|(chunk, (((slots, actions), mut rows), mut reported))| {
                let mut infos = InfoColumns::new(slots.len());
                let mut episodes_ended = 0;
                // One info for the chunk, refilled by every environment in turn.
                let mut info = Info::new();
                // The others still step when one fails, as they would one by one.
                let mut failure = None;
                for (i, slot) in slots.iter_mut().enumerate() {
                    let action = &actions[i * action_dim..(i + 1) * action_dim];
                    let index = chunk * BATCH_CHUNK + i;
                    match slot.step_autoreset(action, options.of(index), &mut info) {
                        Ok(step) => {
                            let (row, context) = slot.observation.split_at(row_dim);
                            rows.push(row, step.reward, step.terminated, step.truncated);
                            episodes_ended += usize::from(step.terminated || step.truncated);
                            if let Some(reported) = &mut reported {
                                reported.note(i, context);
                            }
                            infos.set(i, &info);
                        }
                        Err(e) => {
                            // The rows stay in place; this reply will not be sent.
                            rows.push_failed();
                            failure.get_or_insert_with(|| in_env(index, e));
                        }
                    }
                }
                failure.map_or(Ok((infos, episodes_ended)), Err)
            })
            .collect();
        let (parts, episodes_ended): (Vec<_>, Vec<_>) = chunks
            .into_iter()
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .unzip();
        self.autoresets = episodes_ended.iter().sum();
        self.telemetry.offer(&self.id, &self.envs[0]);
        let info = InfoColumns::merged(&parts);
        let (reply, update_len) = match known_contexts {
            Some(known) => {
                let update = self.reported_contexts.finish(known);
                let update_len = context_update_len(&update);
                (reply.finish_with_contexts(info, &update), update_len)
            }
            None => (reply.finish(info), 0),
        };
        self.info_bytes = self.info_bytes.max(reply.len() - info_offset - update_len);
        Ok(reply.into())
    }

    pub fn expert(&mut self, index: u32) -> Result<Vec<u8>, ErrorReply> {
        let action = self.slot(index)?.env.expert_action()?;
        Ok(encode(&ActionReply {
            v: PROTOCOL_VERSION,
            action: F64s(action),
        }))
    }

    pub fn set_context(&mut self, request: &ContextRequest) -> Result<Vec<u8>, ErrorReply> {
        let context_dim = self.spec.context_space.dim();
        check_vector("context", &request.context.0, context_dim)?;
        let slot = self.slot(request.index)?;
        slot.env.set_context(&request.context.0)?;
        let split = slot.observation.len().saturating_sub(context_dim);
        if slot.observation.len() >= context_dim {
            slot.observation[split..].copy_from_slice(&request.context.0);
        }
        let time = slot.time();
        self.reported_contexts.requested(1);
        Ok(encode(&AckReply {
            v: PROTOCOL_VERSION,
            time,
        }))
    }

    /// Whether environment `index`'s task accepts the context: a vector of the wrong size
    /// or with NaN is an error, a context the task refuses is `valid: false`.
    pub fn check_context(&mut self, request: &ContextRequest) -> Result<Vec<u8>, ErrorReply> {
        check_vector("context", &request.context.0, self.spec.context_space.dim())?;
        let reason = match self
            .slot(request.index)?
            .env
            .check_context(&request.context.0)
        {
            Ok(()) => None,
            Err(error @ EnvError::OutOfBounds { .. }) => Some(full_message(&error)),
            Err(error) => return Err(error.into()),
        };
        Ok(encode(&ContextCheckReply {
            v: PROTOCOL_VERSION,
            valid: reason.is_none(),
            reason,
        }))
    }

    pub fn perturb(&mut self, request: PerturbRequest) -> Result<Vec<u8>, ErrorReply> {
        let slot = self.slot(request.index)?;
        let now = slot.time();
        let message = request.perturbation;
        let start = message.start.unwrap_or(now);
        if !(start.is_finite() && message.duration.is_finite()) {
            return Err(EnvError::NotFinite {
                what: "perturbation start and duration",
            }
            .into());
        }
        if message.duration < 0.0 {
            return Err(ErrorReply::new(
                ErrorCode::OutOfBounds,
                format!("perturbation duration {} must be ≥ 0", message.duration),
            ));
        }
        let kind = match message.kind {
            PerturbationKindMsg::JointTorque { torque } => {
                if torque.iter().any(|t| !t.is_finite()) {
                    return Err(EnvError::NotFinite { what: "torque" }.into());
                }
                PerturbationKind::JointTorque(torque)
            }
            PerturbationKindMsg::LinkWrench {
                link,
                force,
                torque,
            } => {
                if force.iter().chain(&torque).any(|v| !v.is_finite()) {
                    return Err(EnvError::NotFinite { what: "wrench" }.into());
                }
                PerturbationKind::LinkWrench {
                    link: link as usize,
                    force,
                    torque,
                }
            }
        };
        slot.env.perturb(Perturbation {
            kind,
            start,
            duration: message.duration,
        })?;
        Ok(encode(&AckReply {
            v: PROTOCOL_VERSION,
            time: now,
        }))
    }

    /// Renders environment `index`; returns the frame's header and RGB bytes.
    pub fn render(
        &mut self,
        index: u32,
        width: u32,
        height: u32,
    ) -> Result<(FrameHeader, Vec<u8>), ErrorReply> {
        const MAX_SIDE: u32 = 4096;
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(ErrorReply::new(
                ErrorCode::OutOfBounds,
                format!("frame size {width}×{height} outside 1..={MAX_SIDE}"),
            ));
        }
        let pixels = self.slot(index)?.env.render(width, height)?;
        self.frames += 1;
        Ok((
            FrameHeader {
                id: self.frames,
                width,
                height,
            },
            pixels,
        ))
    }

    pub fn time(&self) -> f64 {
        self.envs[0].time()
    }

    fn observation_dim(&self) -> usize {
        self.spec.observation_space.dim()
    }
}

fn in_env(index: usize, error: EnvError) -> ErrorReply {
    let mut reply = ErrorReply::from(error);
    reply.message = format!("environment {index}: {}", reply.message);
    reply
}

/// Gymnasium-style vector info: key → one value per environment, NaN where missing.
///
/// Every environment of a task reports the same keys in the same order, so a value is
/// first tried against the column at its position: one key comparison per value, no map
/// lookup, and a task's `'static` keys are never copied.
struct InfoColumns {
    len: usize,
    columns: Vec<(Cow<'static, str>, Vec<f64>)>,
}

impl InfoColumns {
    fn new(len: usize) -> Self {
        Self {
            len,
            columns: Vec::new(),
        }
    }

    /// Sets environment `index`'s values.
    fn set(&mut self, index: usize, info: &Info) {
        for (position, (key, value)) in info.iter().enumerate() {
            let column = match self.columns.get(position) {
                Some((name, _)) if same_key(name, key) => &mut self.columns[position].1,
                _ => self.column(key),
            };
            column[index] = *value;
        }
    }

    /// The column of `key`, added (all NaN) if there is none yet. Takes the `Cow` itself
    /// (not `&str`) so that a task's `'static` key is kept as a pointer, not copied.
    #[allow(clippy::ptr_arg)]
    fn column(&mut self, key: &Cow<'static, str>) -> &mut Vec<f64> {
        let at = match self.columns.iter().position(|(name, _)| name == key) {
            Some(at) => at,
            None => {
                self.columns.push((key.clone(), vec![f64::NAN; self.len]));
                self.columns.len() - 1
            }
        };
        &mut self.columns[at].1
    }

    /// The values of `key`, if any environment reported it.
    fn values(&self, key: &str) -> Option<&[f64]> {
        self.columns
            .iter()
            .find(|(name, _)| name == key)
            .map(|(_, values)| values.as_slice())
    }

    /// The columns of consecutive parts of a batch as one, as
    /// [`BatchStepWriter::finish`] takes them: every key that any part reports, in
    /// increasing order, with its values part by part (missing from the parts that do not
    /// report it).
    fn merged(
        parts: &[InfoColumns],
    ) -> impl ExactSizeIterator<Item = (&str, impl Iterator<Item = InfoBlock<'_>>)> {
        let keys: BTreeSet<&str> = parts
            .iter()
            .flat_map(|part| part.columns.iter().map(|(key, _)| key.as_ref()))
            .collect();
        keys.into_iter().map(move |key| {
            let blocks = parts.iter().map(move |part| match part.values(key) {
                Some(values) => InfoBlock::Values(values),
                None => InfoBlock::Missing(part.len),
            });
            (key, blocks)
        })
    }

    /// The columns as the protocol carries them.
    fn into_map(self) -> BTreeMap<String, F64s> {
        self.columns
            .into_iter()
            .map(|(key, values)| (key.into_owned(), F64s(values)))
            .collect()
    }

    fn from_infos(infos: &[Info]) -> Self {
        let mut columns = Self::new(infos.len());
        for (i, info) in infos.iter().enumerate() {
            columns.set(i, info);
        }
        columns
    }
}

/// Whether two info keys are equal, by address first: a task reports the same `'static`
/// keys at every step, so the bytes rarely need comparing.
fn same_key(a: &str, b: &str) -> bool {
    (std::ptr::eq(a.as_ptr(), b.as_ptr()) && a.len() == b.len()) || a == b
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(pairs: &[(&'static str, f64)]) -> Info {
        pairs.iter().map(|(k, v)| (Cow::Borrowed(*k), *v)).collect()
    }

    /// Keys an environment does not report are NaN in its row, whatever the order in
    /// which the keys first appear, within a chunk and across merged chunks.
    #[test]
    fn columns_hold_every_key_and_nan_where_an_environment_has_none() {
        let first = [
            info(&[("a", 1.0), ("b", 2.0)]),
            info(&[("b", 3.0), ("c", 4.0)]),
            info(&[("a", 5.0), ("b", 6.0), ("c", 7.0)]),
        ];
        let second = [info(&[("d", 8.0)]), info(&[("a", 9.0), ("b", 10.0)])];
        let parts = [
            InfoColumns::from_infos(&first),
            InfoColumns::from_infos(&second),
        ];
        let map: BTreeMap<&str, Vec<f64>> = InfoColumns::merged(&parts)
            .map(|(key, blocks)| {
                let values = blocks.flat_map(|block| match block {
                    InfoBlock::Values(values) => values.to_vec(),
                    InfoBlock::Missing(count) => vec![f64::NAN; count],
                });
                (key, values.collect())
            })
            .collect();
        assert_eq!(
            map.keys().copied().collect::<Vec<_>>(),
            ["a", "b", "c", "d"],
            "keys in increasing order"
        );
        let nan = f64::NAN;
        let expected = [
            ("a", [1.0, nan, 5.0, nan, 9.0]),
            ("b", [2.0, 3.0, 6.0, nan, 10.0]),
            ("c", [nan, 4.0, 7.0, nan, nan]),
            ("d", [nan, nan, nan, 8.0, nan]),
        ];
        assert_eq!(map.len(), expected.len());
        for (key, values) in expected {
            let column = &map[key];
            for (got, want) in column.iter().zip(values) {
                assert!(
                    got == &want || (got.is_nan() && want.is_nan()),
                    "{key}: {column:?}"
                );
            }
        }
    }
}
