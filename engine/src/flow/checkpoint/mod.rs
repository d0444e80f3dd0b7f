//! A checkpoint is a directory holding `config.json` ([`CheckpointConfig`]) and
//! `weights.safetensors` ([`Weights`], F64 or F32, names as in the trainer's `VarStore`);
//! a trained one also `training_split.json` ([`split::TrainingSplit`]).

pub mod config;
pub mod names;
pub mod split;
pub mod weights;

use std::path::Path;

use crate::flow::checkpoint::config::CheckpointConfig;
use crate::flow::checkpoint::weights::Weights;
use crate::flow::error::{FlowError, FlowResult};

pub const CONFIG_FILE: &str = "config.json";
pub const WEIGHTS_FILE: &str = "weights.safetensors";

pub fn read_config(dir: &Path) -> FlowResult<CheckpointConfig> {
    let path = dir.join(CONFIG_FILE);
    let text = std::fs::read_to_string(&path).map_err(|source| FlowError::Io {
        path: path.clone(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| FlowError::Json { path, source })
}

/// Parses the text of a `config.json` received in memory (e.g. over the network).
pub fn parse_config(text: &str) -> FlowResult<CheckpointConfig> {
    serde_json::from_str(text).map_err(FlowError::ConfigText)
}

pub fn write_config(dir: &Path, config: &CheckpointConfig) -> FlowResult<()> {
    let path = dir.join(CONFIG_FILE);
    let text = serde_json::to_string_pretty(config).map_err(|source| FlowError::Json {
        path: path.clone(),
        source,
    })?;
    std::fs::write(&path, text).map_err(|source| FlowError::Io { path, source })
}

/// Reads a checkpoint, checking the task name when `expected_task` is given.
pub fn read(dir: &Path, expected_task: Option<&str>) -> FlowResult<(CheckpointConfig, Weights)> {
    let config = read_config(dir)?;
    check_task(&config, expected_task)?;
    let weights = Weights::load(&dir.join(WEIGHTS_FILE))?;
    Ok((config, weights))
}

/// A checkpoint held in memory: the `config.json` text and the `weights.safetensors`
/// bytes, as [`read`] finds them in a directory.
pub fn from_bytes(
    config_json: &str,
    weights: &[u8],
    expected_task: Option<&str>,
) -> FlowResult<(CheckpointConfig, Weights)> {
    let config = parse_config(config_json)?;
    check_task(&config, expected_task)?;
    Ok((config, Weights::from_safetensors(weights)?))
}

fn check_task(config: &CheckpointConfig, expected_task: Option<&str>) -> FlowResult<()> {
    match expected_task {
        Some(expected) if expected != config.task() => Err(FlowError::TaskMismatch {
            expected: expected.to_owned(),
            found: config.task().to_owned(),
        }),
        _ => Ok(()),
    }
}

/// Writes `config.json` and `weights.safetensors` into `dir` (created if missing).
pub fn write(dir: &Path, config: &CheckpointConfig, weights: &Weights) -> FlowResult<()> {
    std::fs::create_dir_all(dir).map_err(|source| FlowError::Io {
        path: dir.to_owned(),
        source,
    })?;
    write_config(dir, config)?;
    weights.save(&dir.join(WEIGHTS_FILE))
}
