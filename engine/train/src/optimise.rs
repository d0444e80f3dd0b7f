//! The shared minibatch loop: Adam, cosine learning-rate decay, early stopping on a
//! validation score with the best parameters restored, seeded shuffling.

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use tch::nn::{self, OptimizerConfig};
use tch::{Kind, Tensor};

pub use ciflow_engine::training::{Keep, OptimConfig};

use crate::error::{TrainError, TrainResult};

/// Refuses settings the loop cannot run: no epoch, empty batches, a learning rate that
/// is not a positive number.
pub(crate) fn check(config: &OptimConfig) -> TrainResult<()> {
    if config.epochs == 0
        || config.batch_size == 0
        || !(config.learning_rate > 0.0 && config.learning_rate.is_finite())
    {
        return Err(TrainError::InvalidConfig(
            "epochs, batch_size and learning_rate must be positive".into(),
        ));
    }
    Ok(())
}

/// One epoch's figures, handed to the progress callback.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Progress {
    pub epoch: usize,
    pub epochs: usize,
    /// Mean training loss of the epoch.
    pub train_loss: f64,
    /// Validation score (lower is better): NLL per transition for flows, MSE for the
    /// baseline, on the held-out episodes; the training loss when none are held out.
    pub validation: f64,
    pub best_validation: f64,
    /// Whether this epoch set a new best validation score.
    pub improved: bool,
    pub learning_rate: f64,
}

/// Runs the loop over `samples` minibatch rows; `loss(indices)` returns the batch loss,
/// `validation()` the held-out score (`None` when nothing is held out: the epoch's
/// training loss stands in for it, so training fits every episode). Returns the history and the best epoch; `vs` holds the best
/// parameters on return.
pub fn optimise(
    vs: &nn::VarStore,
    samples: usize,
    config: &OptimConfig,
    mut loss: impl FnMut(&Tensor) -> Tensor,
    mut validation: impl FnMut() -> Option<f64>,
    mut progress: impl FnMut(&Progress),
) -> TrainResult<(Vec<Progress>, usize)> {
    check(config)?;
    let mut opt = nn::Adam::default().build(vs, config.learning_rate)?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut order: Vec<i64> = (0..samples as i64).collect();
    let mut history = Vec::new();
    let (mut best, mut best_epoch) = (f64::INFINITY, 0);
    let mut snapshot = snapshot_of(vs);
    for epoch in 0..config.epochs {
        let phase = epoch as f64 / config.epochs.max(2).saturating_sub(1) as f64;
        let floor = config.final_lr_fraction;
        let lr = config.learning_rate
            * (floor + (1.0 - floor) * 0.5 * (1.0 + (std::f64::consts::PI * phase).cos()));
        opt.set_lr(lr);
        order.shuffle(&mut rng);
        let (mut total, mut batches) = (0.0, 0);
        for chunk in order.chunks(config.batch_size) {
            let batch_loss = loss(&Tensor::from_slice(chunk));
            let value = batch_loss.double_value(&[]);
            if !value.is_finite() {
                return Err(TrainError::Diverged { epoch });
            }
            opt.backward_step_clip_norm(&batch_loss, config.max_grad_norm);
            total += value;
            batches += 1;
        }
        let train_loss = total / batches as f64;
        let score = tch::no_grad(&mut validation).unwrap_or(train_loss);
        let improved = score < best;
        if improved {
            best = score;
            best_epoch = epoch;
            snapshot = snapshot_of(vs);
        }
        let record = Progress {
            epoch: epoch + 1,
            epochs: config.epochs,
            train_loss,
            validation: score,
            best_validation: best,
            improved,
            learning_rate: lr,
        };
        progress(&record);
        history.push(record);
        if epoch - best_epoch >= config.patience {
            break;
        }
    }
    match config.keep {
        Keep::BestValidation => {
            restore(vs, &snapshot);
            Ok((history, best_epoch + 1))
        }
        Keep::Last => {
            let last = history.len();
            Ok((history, last))
        }
    }
}

fn snapshot_of(vs: &nn::VarStore) -> Vec<(String, Tensor)> {
    vs.variables()
        .into_iter()
        .map(|(name, t)| (name, t.detach().copy()))
        .collect()
}

fn restore(vs: &nn::VarStore, snapshot: &[(String, Tensor)]) {
    let variables = vs.variables();
    tch::no_grad(|| {
        for (name, value) in snapshot {
            variables[name].shallow_clone().copy_(value);
        }
    });
}

/// Mean of a per-row tensor as `f64`.
pub fn mean_value(t: &Tensor) -> f64 {
    t.mean(Kind::Double).double_value(&[])
}
