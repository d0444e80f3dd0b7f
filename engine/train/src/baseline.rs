//! Training of the unconstrained behaviour-cloning baseline
//! `ỹ_{k+1} = ỹ_k + dt · MLP(ỹ_k, c̃)` by least squares on the normalised finite
//! differences — the negative control of the stability check.

use std::collections::BTreeMap;
use std::io::ErrorKind;
use std::path::Path;

use ciflow_engine::flow::{BaselineConfig, CheckpointConfig, Goal};
use serde::{Deserialize, Serialize};
use tch::{Kind, Tensor, nn};

use crate::data::{Demonstrations, Transitions};
use crate::error::{TrainError, TrainResult};
use crate::nn::mlp::Mlp;
use crate::nn::row;
use crate::optimise::{OptimConfig, Progress, mean_value, optimise};
use crate::trainer::{TrainConfig, check_threads, double_var_store, save_trained};
use ciflow_engine::flow::checkpoint::names::NET;
use ciflow_engine::flow::checkpoint::split::{SPLIT_FILE, TrainingSplit};
use ciflow_engine::flow::checkpoint::{CONFIG_FILE, WEIGHTS_FILE};

/// The subdirectory of a flow's checkpoint that holds the baseline trained beside it, on
/// the same demonstrations (`ciflow train --baseline`).
pub const BASELINE_DIR: &str = "baseline";

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BaselineTrainConfig {
    pub task: String,
    /// Recorded in the checkpoint ([`BaselineConfig::task_kwargs`]).
    #[serde(default)]
    pub task_kwargs: BTreeMap<String, serde_json::Value>,
    pub hidden: Vec<usize>,
    /// Where the demonstrations go (used only to score convergence).
    pub goal: Goal,
    pub validation_fraction: f64,
    pub threads: i32,
    pub optim: OptimConfig,
}

impl BaselineTrainConfig {
    /// The baseline's standing settings: hidden widths 64-64, 20% of the episodes held out
    /// for early stopping, the optimiser's defaults ([`OptimConfig::default`]).
    pub fn new(task: &str, goal: Goal) -> Self {
        Self {
            task: task.to_owned(),
            task_kwargs: BTreeMap::new(),
            hidden: vec![64, 64],
            goal,
            validation_fraction: 0.2,
            threads: 1,
            optim: OptimConfig::default(),
        }
    }

    /// The baseline matched to a flow's training: its budget, widths and validation
    /// split, with the rollouts' goal where the flow's target is (the context entries it
    /// reads, or else the demonstrations' mean final state).
    pub fn matching(flow: &TrainConfig, data: &Demonstrations) -> Self {
        let goal = match &flow.goal_context_indices {
            Some(indices) => Goal::ContextIndices {
                indices: indices.clone(),
            },
            None => Goal::State {
                value: data.mean_final_state(),
            },
        };
        Self {
            task: flow.task.clone(),
            task_kwargs: flow.task_kwargs.clone(),
            hidden: flow.hidden.clone(),
            goal,
            validation_fraction: flow.validation_fraction,
            threads: flow.threads,
            optim: flow.optim.clone(),
        }
    }
}

#[derive(Debug)]
pub struct TrainedBaseline {
    pub config: BaselineConfig,
    pub var_store: nn::VarStore,
    pub history: Vec<Progress>,
    pub best_epoch: usize,
    /// The demonstrations fitted and those held out for validation.
    pub split: TrainingSplit,
}

impl TrainedBaseline {
    /// Writes `config.json`, `weights.safetensors` and `training_split.json`.
    pub fn save(&self, dir: &Path) -> TrainResult<()> {
        save_trained(
            dir,
            &CheckpointConfig::MlpBaseline(self.config.clone()),
            &self.var_store,
            &self.split,
        )
    }
}

/// Removes the baseline checkpoint an earlier run left in the flow checkpoint `dir` (in
/// its [`BASELINE_DIR`]), so that a baseline found beside a flow was trained in the same
/// run. Only the checkpoint's own files go, and the subdirectory if that empties it:
/// anything else in it is the user's.
pub fn remove_stale_baseline(dir: &Path) -> TrainResult<()> {
    let baseline = dir.join(BASELINE_DIR);
    if !baseline.is_dir() {
        return Ok(());
    }
    let stale = |source| TrainError::StaleBaseline {
        path: baseline.clone(),
        source,
    };
    for file in [CONFIG_FILE, WEIGHTS_FILE, SPLIT_FILE] {
        match std::fs::remove_file(baseline.join(file)) {
            Err(e) if e.kind() != ErrorKind::NotFound => return Err(stale(e)),
            _ => {}
        }
    }
    match std::fs::remove_dir(&baseline) {
        Err(e) if e.kind() != ErrorKind::DirectoryNotEmpty => Err(stale(e)),
        _ => Ok(()),
    }
}

pub fn train_baseline(
    data: &Demonstrations,
    train: &BaselineTrainConfig,
    progress: impl FnMut(&Progress),
) -> TrainResult<TrainedBaseline> {
    check_threads(train.threads)?;
    let (d, m) = data.validate()?;
    let split = data.split(train.validation_fraction, train.optim.seed);
    let config = BaselineConfig {
        task: train.task.clone(),
        task_kwargs: train.task_kwargs.clone(),
        state_dim: d,
        context_dim: m,
        dt: data.dt,
        hidden: train.hidden.clone(),
        goal: train.goal.clone(),
        normalisation: split.normalisation(&[], None),
        bounds: split.bounds(),
    };
    config.validate()?;
    tch::set_num_threads(train.threads);
    tch::manual_seed(train.optim.seed as i64);
    let vs = double_var_store();
    let net = Mlp::new(&(vs.root() / NET), &config.mlp_sizes(), false);
    let norm = &config.normalisation;
    let (state_mean, state_std) = (row(&norm.state_mean), row(&norm.state_std));
    let (context_mean, context_std) = (row(&norm.context_mean), row(&norm.context_std));
    let prepare = |t: &Transitions| {
        let pairs = t.one_step();
        let prev = (pairs.prev - &state_mean) / &state_std;
        let next = (pairs.next - &state_mean) / &state_std;
        let context = (pairs.context - &context_mean) / &context_std;
        let velocity = (next - &prev) / data.dt;
        (Tensor::cat(&[&prev, &context], 1), velocity)
    };
    let (inputs, targets) = prepare(&Transitions::new(&split.fitted, d, m));
    let check =
        (!split.held_out.is_empty()).then(|| prepare(&Transitions::new(&split.held_out, d, m)));
    let mse = |x: &Tensor, y: &Tensor| (net.forward(x) - y).square().mean(Kind::Double);
    let loss = |batch: &Tensor| {
        mse(
            &inputs.index_select(0, batch),
            &targets.index_select(0, batch),
        )
    };
    let validation = || check.as_ref().map(|(x, y)| mean_value(&mse(x, y)));
    let samples = inputs.size()[0] as usize;
    let (history, best_epoch) = optimise(&vs, samples, &train.optim, loss, validation, progress)?;
    Ok(TrainedBaseline {
        config,
        var_store: vs,
        history,
        best_epoch,
        split: split.recorded(),
    })
}
