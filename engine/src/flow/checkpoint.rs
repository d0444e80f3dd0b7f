//! A checkpoint is a directory holding `config.json` ([`CheckpointConfig`]) and
//! `weights.safetensors` ([`Weights`], F64 or F32, names as in the trainer's `VarStore`).

use std::path::Path;

use super::config::CheckpointConfig;
use super::error::{FlowError, FlowResult};
use super::weights::Weights;

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
    if let Some(expected) = expected_task
        && expected != config.task()
    {
        return Err(FlowError::TaskMismatch {
            expected: expected.to_owned(),
            found: config.task().to_owned(),
        });
    }
    let weights = Weights::load(&dir.join(WEIGHTS_FILE))?;
    Ok((config, weights))
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
