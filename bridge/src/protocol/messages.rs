//! Request and reply payloads: MessagePack maps with the field names below (encode with
//! named fields; `rmp_serde::to_vec_named`). Vectors of reals are [`F64s`]. Every request
//! carries the protocol version `v`; session requests also carry the owner's `token`.

use std::collections::BTreeMap;

use ciflow_envs::registry::Kwargs;
use ciflow_envs::{EnvSpec, Info, ResetOptions};
use ciflow_evaluation::stability::{Ending, StabilityConfig};
use ciflow_evaluation::stability_check::Subject;
use ciflow_evaluation::{EpisodeBatch, EvaluationConfig};
use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;

use super::wire::{bin_only, reset_options};
use super::{F64Bin, F64s};
use crate::limits::{Limits, Usage};

/// The fields every request may carry: its version, and how long the caller will wait.
/// Decoded before the full request, to tell a version mismatch from garbage.
#[derive(Debug, Deserialize)]
pub struct Header {
    pub v: u16,
    /// Milliseconds the caller will wait for the reply; the engine answers
    /// `deadline_exceeded` rather than work past it (at most its own budget).
    #[serde(default)]
    pub deadline_ms: Option<u32>,
}

// ---------------------------------------------------------------- engine-level queries

/// `…/tasks`: `{v}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TasksRequest {
    pub v: u16,
}

/// Reply to `…/tasks`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TasksReply {
    pub v: u16,
    /// The engine's name, the `<engine>` chunk of its keys.
    pub engine: String,
    pub tasks: Vec<TaskInfo>,
    pub policies: Vec<PolicyInfo>,
}

/// One task an engine can make.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TaskInfo {
    /// Short command-line name, e.g. `pouring`.
    pub name: String,
    pub spec: EnvSpec,
}

impl TaskInfo {
    /// Whether `task` names this task: its Gymnasium id or its short name.
    pub fn is_named(&self, task: &str) -> bool {
        self.spec.id == task || self.name == task
    }
}

/// One policy an engine evaluates with `…/policy/<name>/act`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolicyInfo {
    pub name: String,
    /// The task whose observations it reads, e.g. `ciflow/Pouring-v0`.
    pub task: String,
    pub observation_dim: u32,
    pub action_dim: u32,
    /// Training epoch of the loaded checkpoint, when its publisher said.
    #[serde(default)]
    pub epoch: Option<u64>,
    /// Validation negative log-likelihood of the loaded checkpoint, when known.
    #[serde(default)]
    pub validation_nll: Option<f64>,
}

/// `…/client/<identity>/make`: opens a session of `num_envs` copies of `task`, owned by
/// the client process `<identity>/<instance>`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MakeRequest {
    pub v: u16,
    /// Which process of `<identity>` owns the session; its liveliness token
    /// `ciflow/v2/alive/client/<identity>/<instance>` must be declared first. When the
    /// token goes away the session is closed.
    pub instance: String,
    /// Gymnasium id or short name.
    pub task: String,
    /// Number of environments stepped together by `step_batch` (default 1).
    #[serde(default = "one")]
    pub num_envs: u32,
    /// Construction arguments of the task (numbers), e.g. `{"obstacles": 2}`.
    #[serde(default)]
    pub kwargs: Kwargs,
    /// How long the caller waits, in milliseconds (see [`Header::deadline_ms`]): a `make`
    /// that would outlive the caller builds nothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_ms: Option<u32>,
}

fn one() -> u32 {
    1
}

/// Reply to `…/make`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MakeReply {
    pub v: u16,
    /// The `<session>` chunk of the session's keys. Not a secret.
    pub session: String,
    /// The session's secret: 16 bytes every later request must echo in `token`.
    pub token: ByteBuf,
    pub num_envs: u32,
    pub spec: EnvSpec,
}

/// `…/client/<identity>/limits`: the engine's bounds, and the usage of them by the process
/// `<identity>/<instance>` when named.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LimitsRequest {
    pub v: u16,
    #[serde(default)]
    pub instance: Option<String>,
}

/// Reply to `…/limits`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LimitsReply {
    pub v: u16,
    pub limits: Limits,
    /// The named client's sessions and environments (zero for an unknown client).
    #[serde(default)]
    pub usage: Option<Usage>,
}

// ---------------------------------------------------------------- session queries

/// `…/reset` (single environment) and `…/reset_batch` (all environments; environment
/// `i` is seeded with `seed + i`, or with `seeds[i]`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ResetRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    pub seed: Option<u64>,
    /// `reset_batch` only, instead of `seed`: one seed per environment (`None`: that
    /// environment's RNG continues).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seeds: Option<Vec<Option<u64>>>,
    #[serde(default, deserialize_with = "reset_options")]
    pub options: Option<ResetOptions>,
}

/// How the environments of a batch are seeded at reset.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BatchSeeds {
    /// Every environment's RNG continues (an unseeded reset).
    Continue,
    /// Environment `i` gets `seed + i`.
    From(u64),
    /// Environment `i` gets entry `i` (`None`: its RNG continues).
    Each(Vec<Option<u64>>),
}

impl From<Option<u64>> for BatchSeeds {
    fn from(seed: Option<u64>) -> Self {
        seed.map_or(Self::Continue, Self::From)
    }
}

impl BatchSeeds {
    /// The seeds of a request's `seed` and `seeds` (at most one of them).
    pub fn of_request(seed: Option<u64>, seeds: Option<Vec<Option<u64>>>) -> Option<Self> {
        match (seed, seeds) {
            (Some(_), Some(_)) => None,
            (_, Some(seeds)) => Some(Self::Each(seeds)),
            (seed, None) => Some(seed.into()),
        }
    }

    /// The request fields `(seed, seeds)` that carry these seeds.
    pub fn into_request(self) -> (Option<u64>, Option<Vec<Option<u64>>>) {
        match self {
            Self::Continue => (None, None),
            Self::From(seed) => (Some(seed), None),
            Self::Each(seeds) => (None, Some(seeds)),
        }
    }

    /// Environment `i`'s seed.
    pub fn of(&self, i: usize) -> Option<u64> {
        match self {
            Self::Continue => None,
            Self::From(seed) => Some(seed.wrapping_add(i as u64)),
            Self::Each(seeds) => seeds[i],
        }
    }

    /// The seeds of the environments `envs` of the batch, as a batch of their own.
    pub fn share(&self, envs: std::ops::Range<usize>) -> Self {
        match self {
            Self::Continue => Self::Continue,
            Self::From(seed) => Self::From(seed.wrapping_add(envs.start as u64)),
            Self::Each(seeds) => Self::Each(seeds[envs].to_vec()),
        }
    }

    /// The number of environments these seeds are for, if they say.
    pub fn count(&self) -> Option<usize> {
        match self {
            Self::Each(seeds) => Some(seeds.len()),
            Self::Continue | Self::From(_) => None,
        }
    }
}

/// Reply to `…/reset`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResetReply {
    pub v: u16,
    pub observation: F64s,
    pub info: Info,
}

/// `…/step`: one control period of a single-environment session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    pub action: F64s,
}

/// Reply to `…/step`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepReply {
    pub v: u16,
    pub observation: F64s,
    pub reward: f64,
    pub terminated: bool,
    pub truncated: bool,
    pub info: Info,
    /// Simulated seconds since the reset, after this step.
    pub time: f64,
}

/// Reply to `…/reset_batch`: observations row-major `num_envs × obs_dim`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchResetReply {
    pub v: u16,
    pub observations: F64s,
    /// Info columns: key → `num_envs` values, NaN where an environment had no such key.
    pub info: BTreeMap<String, F64s>,
}

/// `…/step_batch`: actions row-major `num_envs × action_dim`. Clients send them from
/// their own memory ([`F64Slice`](super::F64Slice)); the engine decodes [`F64s`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchStepRequest<A = F64s> {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    pub actions: A,
    /// With it, the reply leaves the contexts out of its observations and sends in
    /// [`BatchStepReply::contexts`] only those that changed after this epoch: the epoch of
    /// the last reply whose contexts the client holds (0: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub known_contexts: Option<u64>,
}

/// Reply to `…/step_batch`, with Gymnasium's next-step autoreset: an environment whose
/// episode ended on the previous call ignores its action, resets (RNG continuing, the
/// last `reset_batch` options) and reports the first observation, reward 0 and both flags
/// false.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchStepReply {
    pub v: u16,
    pub observations: F64s,
    pub rewards: F64s,
    /// One byte per environment, 0 or 1.
    pub terminated: ByteBuf,
    pub truncated: ByteBuf,
    /// Info columns, as in [`BatchResetReply::info`].
    pub info: BTreeMap<String, F64s>,
    /// Present when the request gave [`BatchStepRequest::known_contexts`]: the
    /// observations are then `num_envs × (obs_dim - context_dim)`, each without its
    /// context, and these are the contexts the client does not hold yet.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contexts: Option<ContextUpdate>,
}

/// The contexts of a batch that changed after the epoch a client gave, by a reset, an
/// autoreset, a `context` request or the task itself: the client's copy of every context
/// is current once it applies them and takes `epoch` as the one it holds.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ContextUpdate {
    pub epoch: u64,
    /// The environments whose context changed, in increasing order.
    pub envs: Vec<u32>,
    /// Their contexts, row-major `envs.len() × context_dim`.
    pub values: F64s,
}

/// A [`ContextUpdate`] read in place.
#[derive(Debug, Deserialize)]
pub struct ContextUpdateView<'a> {
    pub epoch: u64,
    pub envs: Vec<u32>,
    #[serde(borrow)]
    pub values: F64Bin<'a>,
}

/// A [`BatchStepReply`] read in place, its columns borrowed from the payload: a client
/// copies them once, straight to where it keeps the batch
/// ([`crate::vector::step_batches_into`]).
#[derive(Debug, Deserialize)]
pub struct BatchStepReplyView<'a> {
    pub v: u16,
    #[serde(borrow)]
    pub observations: F64Bin<'a>,
    #[serde(borrow)]
    pub rewards: F64Bin<'a>,
    #[serde(borrow)]
    pub terminated: &'a serde_bytes::Bytes,
    #[serde(borrow)]
    pub truncated: &'a serde_bytes::Bytes,
    #[serde(borrow)]
    pub info: BTreeMap<&'a str, F64Bin<'a>>,
    #[serde(borrow, default)]
    pub contexts: Option<ContextUpdateView<'a>>,
}

/// `…/expert` (`{v, token, index}`) and `…/close` (`{v, token}`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    /// Which environment of the session (default 0).
    #[serde(default)]
    pub index: u32,
}

/// Reply to `…/expert` and to `…/policy/<name>/act`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ActionReply {
    pub v: u16,
    pub action: F64s,
}

/// `…/context`: replaces the context of environment `index` mid-episode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContextRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    #[serde(default)]
    pub index: u32,
    pub context: F64s,
}

/// Reply to `…/check_context` (a [`ContextRequest`]): whether the task accepts the
/// context, and if not, why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContextCheckReply {
    pub v: u16,
    pub valid: bool,
    #[serde(default)]
    pub reason: Option<String>,
}

/// `…/perturb`: schedules a perturbation of environment `index`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PerturbRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    #[serde(default)]
    pub index: u32,
    pub perturbation: PerturbationMsg,
}

/// An external push on the robot during `[start, start + duration)` simulated seconds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PerturbationMsg {
    #[serde(flatten)]
    pub kind: PerturbationKindMsg,
    /// Simulated seconds since the reset; absent means "now" (the session's time).
    pub start: Option<f64>,
    pub duration: f64,
}

/// What pushes: `{kind: "joint_torque", torque}` or
/// `{kind: "link_wrench", link, force, torque}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PerturbationKindMsg {
    /// Generalized forces added to `τ`, one per joint (N·m or N).
    JointTorque { torque: Vec<f64> },
    /// A wrench at the origin of movable link number `link` (0 = first), world-aligned
    /// (N, N·m).
    LinkWrench {
        link: u32,
        force: [f64; 3],
        torque: [f64; 3],
    },
}

/// Acknowledges `…/context`, `…/perturb` and `…/close`: the session's simulated time when
/// the request took effect.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AckReply {
    pub v: u16,
    pub time: f64,
}

/// `…/describe`: `{v}` (no token: it tells what the session is, not how to drive it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DescribeRequest {
    pub v: u16,
}

/// Reply to `…/describe`: the task and the construction arguments the session was made
/// with, so that a viewer can draw its telemetry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DescribeReply {
    pub v: u16,
    /// The Gymnasium id.
    pub task: String,
    pub kwargs: Kwargs,
    pub num_envs: u32,
}

/// `…/render`: the frame is published on `…/session/<session>/frame`; subscribe first.
/// The environments of a session of more than one draw no trail: they keep none.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderRequest {
    pub v: u16,
    #[serde(deserialize_with = "bin_only")]
    pub token: ByteBuf,
    #[serde(default)]
    pub index: u32,
    pub width: u32,
    pub height: u32,
}

/// Reply to `…/render`, sent after the frame was published. The frame's publication
/// carries the same [`FrameHeader`] as its attachment.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderReply {
    pub v: u16,
    pub frame: FrameHeader,
}

/// Identifies a published frame: payload is `height × width × 3` RGB bytes, row-major.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameHeader {
    /// Increases by one per frame of the session.
    pub id: u64,
    pub width: u32,
    pub height: u32,
}

// ---------------------------------------------------------------- policies

/// `…/policy/<name>/act`: `n` observations row-major in, `n` actions out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ActRequest {
    pub v: u16,
    pub observations: F64s,
    /// How long the caller waits, in milliseconds (see [`Header::deadline_ms`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_ms: Option<u32>,
}

/// `…/policy/<name>/evaluate`: closed-loop episodes `first..first + count` of the
/// evaluation `config` of the (checkpoint) policy `<name>`, in its task built with the
/// policy's construction arguments — one share of an evaluation spread over engines.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluateRequest {
    pub v: u16,
    pub config: EvaluationConfig,
    pub first: u64,
    pub count: u64,
    /// How long the caller waits, in milliseconds (see [`Header::deadline_ms`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_ms: Option<u32>,
}

/// Reply to `…/policy/<name>/evaluate`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluateReply {
    pub v: u16,
    pub batch: EpisodeBatch,
}

/// `…/policy/<name>/stability`: the endings of the observation-space rollouts
/// `first..first + count` of the stability check `config` of the (checkpoint) policy
/// `<name>` or of its negative control — one share of `ciflow stability --engines`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StabilityRequest {
    pub v: u16,
    pub subject: Subject,
    pub config: StabilityConfig,
    pub first: u64,
    pub count: u64,
    /// How long the caller waits, in milliseconds (see [`Header::deadline_ms`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_ms: Option<u32>,
}

/// Reply to `…/policy/<name>/stability`: one ending per rollout, in order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StabilityReply {
    pub v: u16,
    pub endings: Vec<Ending>,
}

// ---------------------------------------------------------------- publications

/// Published on `…/session/<session>/telemetry` for environment 0 while a subscriber
/// matches, at most `telemetry_hz` times per wall-clock second.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Telemetry {
    pub v: u16,
    pub session: String,
    /// Steps since the reset.
    pub step: u64,
    /// Simulated seconds since the reset.
    pub time: f64,
    /// The observation without its context tail: the robot's state.
    pub state: F64s,
    /// The last action (desired acceleration) applied.
    pub command: F64s,
    pub context: F64s,
    pub reward: f64,
    /// A policy drives the session (`run`) and will take the next step.
    #[serde(default)]
    pub running: bool,
    /// The episode ended (terminated or truncated) with this sample.
    #[serde(default)]
    pub episode_done: bool,
    /// An external force (a push) acted during this sample's step, for the tasks that
    /// report it (`info["perturbed"]`: pouring, reach).
    #[serde(default)]
    pub perturbed: bool,
}
