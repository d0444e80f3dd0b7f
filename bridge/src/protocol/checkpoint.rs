//! Messages of policies served by the engine: checkpoints published by a trainer for
//! hot-loading, and `run`, which lets a policy drive a session.

use ciflow_envs::registry::Kwargs;
use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;

/// Published on `ciflow/v2/policies/<name>/checkpoint`: a whole checkpoint directory in
/// one message (the `config.json` text and the `weights.safetensors` bytes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMsg {
    pub v: u16,
    /// The policy's name; must equal the `<name>` chunk of the key.
    pub name: String,
    /// The task the checkpoint was trained for (as in its configuration).
    pub task: String,
    /// The text of `config.json`.
    pub config: String,
    /// The bytes of `weights.safetensors`.
    pub weights: ByteBuf,
    pub epoch: u64,
    pub validation_nll: f64,
    /// Construction arguments of the task (e.g. `{obstacles: 1}`); absent or empty: those
    /// of the policy it replaces, else the task's defaults.
    #[serde(default)]
    pub kwargs: Kwargs,
    /// The trainer's signature (see [`crate::signing`]); absent: unsigned.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signature: Option<CheckpointSignature>,
}

/// `{key: bin(32), signature: bin(64)}`: an ed25519 public key and its signature of the
/// message (see [`crate::signing`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointSignature {
    pub key: ByteBuf,
    pub signature: ByteBuf,
}

/// `…/session/<session>/run`: the engine steps environment `index` with `policy`'s action
/// once per control period, paced to wall-clock × `speed`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunRequest {
    pub v: u16,
    #[serde(deserialize_with = "super::wire::bin_only")]
    pub token: ByteBuf,
    #[serde(default)]
    pub index: u32,
    pub policy: String,
    /// 1 = real time at the control rate, 2 = twice as fast, 0 = as fast as possible.
    #[serde(default = "real_time")]
    pub speed: f64,
    /// Steps to take; absent: until the episode ends.
    #[serde(default)]
    pub steps: Option<u32>,
}

fn real_time() -> f64 {
    1.0
}
