//! Which demonstrations a checkpoint was fitted to and which its training held out for
//! validation: `training_split.json` beside `config.json`.
//!
//! Each episode is named by what its environment made of it at reset — the seed it was
//! recorded with, its first position `q_0` and its first context `c_0` — so that an
//! evaluation that replays the recording's seeds can say which of its episodes the model
//! fitted, which it never fitted, and which are not in the data at all (another task
//! variant or reset option gives the same seed another start, and then no match).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::flow::error::{FlowError, FlowResult};

pub const SPLIT_FILE: &str = "training_split.json";

/// One demonstration as it started.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeStart {
    /// The seed passed to `reset` when it was recorded, if any.
    pub seed: Option<u64>,
    /// `q_0`, the position at reset.
    pub position: Vec<f64>,
    /// `c_0`, the context at reset.
    pub context: Vec<f64>,
}

/// The demonstrations a training run fitted and those it held out (for early stopping).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainingSplit {
    pub fitted: Vec<EpisodeStart>,
    pub held_out: Vec<EpisodeStart>,
}

/// Where an evaluated episode stands in a [`TrainingSplit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplitRole {
    Fitted,
    HeldOut,
    /// Not among the demonstrations (or recorded without a seed).
    NotInData,
}

impl TrainingSplit {
    /// The role of the episode reset with `seed` that started at `position` in
    /// `context`: the start must match the recorded one exactly, as a replay of the
    /// recording's seed in the same environment reproduces it.
    pub fn role(&self, seed: u64, position: &[f64], context: &[f64]) -> SplitRole {
        let matches = |e: &EpisodeStart| {
            e.seed == Some(seed) && e.position == position && e.context == context
        };
        if self.fitted.iter().any(matches) {
            SplitRole::Fitted
        } else if self.held_out.iter().any(matches) {
            SplitRole::HeldOut
        } else {
            SplitRole::NotInData
        }
    }
}

/// Writes `split` as `dir/training_split.json` (compact: a split of thousands of episodes).
pub fn write_split(dir: &Path, split: &TrainingSplit) -> FlowResult<()> {
    let path = dir.join(SPLIT_FILE);
    let text = serde_json::to_string(split).map_err(|source| FlowError::Json {
        path: path.clone(),
        source,
    })?;
    std::fs::write(&path, text).map_err(|source| FlowError::Io { path, source })
}

/// Reads `dir/training_split.json`; `None` when the checkpoint has none (written by
/// hand, or before splits were recorded).
pub fn read_split(dir: &Path) -> FlowResult<Option<TrainingSplit>> {
    let path = dir.join(SPLIT_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(FlowError::Io { path, source }),
    };
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|source| FlowError::Json { path, source })
}
