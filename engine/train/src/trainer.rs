//! Maximum-likelihood training of a conditioned ImitationFlow (the paper's Appendix
//! "Behavioural Cloning Learning"). What is maximised, precisely:
//!
//! - `horizon = 1`, `arrival = 0`, `state_noise = 0`: the exact log-likelihood of the
//!   demonstrations, `Σ_i [log p(y₀ⁱ | c₀ⁱ) + Σ_t log p(y_tⁱ | y_{t-1}ⁱ, c_{t-1}ⁱ)]`,
//!   minibatched over transitions (the initial-state term enters every batch scaled by
//!   episodes / transitions, so an epoch's expected gradient is that of the full objective
//!   divided by the number of transitions);
//! - `horizon = K > 1`: each row is a span `y_t → y_{t+k}`, `k ~ U{1, …, min(K, T - t)}`,
//!   scored with the model's `k`-step density `p(y_{t+k} | y_t, c_t)` — ImitationFlow's
//!   multi-step windows. The objective is then a composite likelihood (a sum of span
//!   log-densities, which overlap), not the joint one: it asks the noise-free `k`-step map
//!   to land where the demonstration is `k` steps later, so a field that matches each
//!   step but drifts across several (cutting a corner) scores worse;
//! - `arrival = p > 0`: a share `p` of the rows span instead every step left in their
//!   episode, `y_t → y_T`, scored the same way: where and when the motion ends;
//! - `state_noise > 0`: the likelihood of states jittered by Gaussian noise, a smoothed
//!   density that keeps deterministic expert data's likelihood bounded.

use std::path::Path;

use ciflow_engine::flow::checkpoint::config::validate_context_sets;
use ciflow_engine::flow::checkpoint::split::{TrainingSplit, write_split};
use ciflow_engine::flow::checkpoint::{self, WEIGHTS_FILE};
use ciflow_engine::flow::{CheckpointConfig, FlowConfig};
pub use ciflow_engine::training::{DEFAULT_STATE_NOISE, TrainConfig};
use tch::{Device, Kind, Tensor, nn};

use crate::data::{Demonstrations, Split, Transitions};
use crate::error::{TrainError, TrainResult};
use crate::latent::LatentInit;
use crate::optimise::{Progress, mean_value, optimise};
use crate::policy::FlowModel;

/// Initial states drawn per minibatch for the `log p(y₀ | c₀)` term.
const INITIAL_ROWS_PER_BATCH: usize = 16;
/// Most libtorch intra-op threads a run may ask for. libtorch aborts the process (stack
/// overflow) when asked for 100 000 (10 000 still run), and these small networks gain
/// nothing from more than a few; 1024 leaves room for any workstation's cores.
pub const MAX_THREADS: i32 = 1024;

/// A trained flow: its engine configuration and parameters.
#[derive(Debug)]
pub struct TrainedFlow {
    pub config: FlowConfig,
    pub var_store: nn::VarStore,
    pub model: FlowModel,
    pub history: Vec<Progress>,
    /// The epoch whose parameters were kept (best validation NLL).
    pub best_epoch: usize,
    /// The demonstrations fitted and those held out for validation.
    pub split: TrainingSplit,
}

impl TrainedFlow {
    /// Writes `config.json`, `weights.safetensors` (loadable by `Policy::load`) and
    /// `training_split.json`.
    pub fn save(&self, dir: &Path) -> TrainResult<()> {
        save_trained(
            dir,
            &CheckpointConfig::Flow(self.config.clone()),
            &self.var_store,
            &self.split,
        )
    }
}

/// The flow's parameters as they are during training, handed to the progress callback.
pub struct Snapshot<'a> {
    config: &'a FlowConfig,
    var_store: &'a nn::VarStore,
    split: &'a TrainingSplit,
}

impl Snapshot<'_> {
    /// Writes the current parameters as a checkpoint directory, as [`TrainedFlow::save`].
    pub fn save(&self, dir: &Path) -> TrainResult<()> {
        save_trained(
            dir,
            &CheckpointConfig::Flow(self.config.clone()),
            self.var_store,
            self.split,
        )
    }
}

/// A trained model's checkpoint: [`save_checkpoint`] and the demonstrations' `split`.
pub(crate) fn save_trained(
    dir: &Path,
    config: &CheckpointConfig,
    vs: &nn::VarStore,
    split: &TrainingSplit,
) -> TrainResult<()> {
    save_checkpoint(dir, config, vs)?;
    Ok(write_split(dir, split)?)
}

/// Writes a checkpoint directory from a `VarStore`.
pub fn save_checkpoint(
    dir: &Path,
    config: &CheckpointConfig,
    vs: &nn::VarStore,
) -> TrainResult<()> {
    std::fs::create_dir_all(dir).map_err(|source| {
        TrainError::Flow(ciflow_engine::flow::FlowError::Io {
            path: dir.to_owned(),
            source,
        })
    })?;
    checkpoint::write_config(dir, config)?;
    vs.save(dir.join(WEIGHTS_FILE))?;
    Ok(())
}

/// A CPU `VarStore` whose new variables are f64.
pub fn double_var_store() -> nn::VarStore {
    let mut vs = nn::VarStore::new(Device::Cpu);
    vs.set_kind(Kind::Double);
    vs
}

/// Refuses settings [`train_flow`] cannot run whatever the data, so that a command can
/// check them before it loads, trains or writes anything; [`flow_config`] checks them
/// with what needs the data's dimensions (the context sets, say).
pub fn check_config(train: &TrainConfig) -> TrainResult<()> {
    let checks = [
        (train.horizon >= 1, "horizon must be >= 1".to_owned()),
        (
            (0.0..1.0).contains(&train.validation_fraction),
            format!(
                "validation_fraction must be in [0, 1), not {}",
                train.validation_fraction
            ),
        ),
        (
            train.state_noise.is_finite() && train.state_noise >= 0.0,
            format!(
                "state_noise must be finite and >= 0, not {}",
                train.state_noise
            ),
        ),
        (
            (0.0..=1.0).contains(&train.arrival),
            format!(
                "arrival is a share of the training pairs: it must be in [0, 1], not {}",
                train.arrival
            ),
        ),
    ];
    if let Some((_, problem)) = checks.into_iter().find(|(valid, _)| !valid) {
        return Err(TrainError::InvalidConfig(problem));
    }
    // The optimiser's own check, here before the data is prepared.
    crate::optimise::check(&train.optim)?;
    check_threads(train.threads)
}

/// Refuses a libtorch thread count outside `1..=MAX_THREADS`: `tch` panics on fewer
/// than one and libtorch aborts on far too many.
pub(crate) fn check_threads(threads: i32) -> TrainResult<()> {
    if (1..=MAX_THREADS).contains(&threads) {
        Ok(())
    } else {
        Err(TrainError::InvalidConfig(format!(
            "threads must be between 1 and {MAX_THREADS}, not {threads}"
        )))
    }
}

/// Refuses a checkpoint directory `dir` whose nearest existing ancestor (`dir` itself,
/// if it exists) is not a directory, such as a file given for `dir`: writing there would
/// fail only after training.
pub fn check_checkpoint_dir(dir: &Path) -> TrainResult<()> {
    match dir.ancestors().find(|path| path.exists()) {
        Some(taken) if !taken.is_dir() => Err(TrainError::NotADirectory {
            path: taken.to_owned(),
        }),
        _ => Ok(()),
    }
}

/// The engine configuration for `data` under `train`, which [`train_flow`] would run:
/// settings it cannot run are refused here ([`check_config`] and the engine's checks).
pub fn flow_config(data: &Demonstrations, train: &TrainConfig) -> TrainResult<FlowConfig> {
    fitted_config(
        data,
        &data.split(train.validation_fraction, train.optim.seed),
        train,
    )
}

/// [`flow_config`], its statistics taken from the episodes `split` fits.
fn fitted_config(
    data: &Demonstrations,
    split: &Split,
    train: &TrainConfig,
) -> TrainResult<FlowConfig> {
    check_config(train)?;
    let (d, m) = data.validate()?;
    // The statistics are pooled over the context sets and read through the joint range:
    // both must fit the data first (a set reaching past the context would index out of it).
    validate_context_sets(&train.context_sets, m)?;
    if let Some(range) = &train.joint_range {
        range.validate(d)?;
    }
    let config = FlowConfig {
        format: ciflow_engine::flow::checkpoint::config::FORMAT,
        task: train.task.clone(),
        task_kwargs: train.task_kwargs.clone(),
        state_dim: d,
        context_dim: m,
        dt: data.dt,
        latent: train.latent,
        min_rate: train.min_rate,
        coupling: train.coupling.clone(),
        layers: train.layers,
        hidden: train.hidden.clone(),
        goal_context_indices: train.goal_context_indices.clone(),
        context_sets: train.context_sets.clone(),
        set_encoder: (!train.context_sets.is_empty()).then(|| train.set_encoder.clone()),
        contractions: train.contractions,
        joint_range: train.joint_range.clone(),
        normalisation: split.normalisation(&train.context_sets, train.joint_range.as_ref()),
        bounds: split.bounds(),
    };
    config.validate()?;
    Ok(config)
}

/// The fitted demonstrations' RMS step per normalised coordinate and starting values of the
/// latent noise, speed and turning rate: the mean angular velocity of the first two
/// normalised coordinates about the cycle's centre (the data's mean) or, for go-to
/// motions, about where each demonstration ends.
fn latent_init(split: &Split, config: &FlowConfig) -> (f64, LatentInit) {
    let norm = &config.normalisation;
    let unbounded = |y: &[f64], i: usize| match &config.joint_range {
        Some(range) => range.unbounded(i, y[i]),
        None => y[i],
    };
    let normalised =
        |y: &[f64], i: usize| (unbounded(y, i) - norm.state_mean[i]) / norm.state_std[i];
    let (mut squares, mut angle, mut n) = (0.0, 0.0, 0.0);
    for e in split.fitted_in_data_order() {
        let end = e.states.last().expect("validated episodes are not empty");
        let centre: [f64; 2] = match config.latent.is_go_to() {
            true => [normalised(end, 0), normalised(end, 1)],
            false => [0.0, 0.0],
        };
        let psi = |y: &[f64]| (normalised(y, 1) - centre[1]).atan2(normalised(y, 0) - centre[0]);
        let counted = e
            .states
            .windows(2)
            .enumerate()
            .filter(|(t, _)| e.counts(*t));
        for (_, w) in counted {
            for i in 0..config.state_dim {
                squares += (normalised(&w[1], i) - normalised(&w[0], i)).powi(2);
            }
            let delta = psi(&w[1]) - psi(&w[0]);
            angle += delta.sin().atan2(delta.cos());
            n += 1.0;
        }
    }
    let rms_step = (squares / (n * config.state_dim as f64)).sqrt();
    let init = LatentInit {
        sigma: rms_step.max(1e-3),
        omega: angle / (n * config.dt),
        speed: (rms_step * (config.state_dim as f64).sqrt() / config.dt).max(1e-3),
    };
    (rms_step, init)
}

/// Trains a flow by maximum likelihood (the module's doc says which); `progress` is called once per epoch with
/// its figures and the parameters at its end (to save or publish each better checkpoint).
pub fn train_flow(
    data: &Demonstrations,
    train: &TrainConfig,
    mut progress: impl FnMut(&Progress, &Snapshot),
) -> TrainResult<TrainedFlow> {
    let split = data.split(train.validation_fraction, train.optim.seed);
    let config = fitted_config(data, &split, train)?;
    tch::set_num_threads(train.threads);
    tch::manual_seed(train.optim.seed as i64);
    let vs = double_var_store();
    let (rms_step, init) = latent_init(&split, &config);
    let model = FlowModel::new(&vs.root(), &config, init);
    let (d, m) = (config.state_dim, config.context_dim);
    let fit = Transitions::new(&split.fitted, d, m);
    let check =
        (!split.held_out.is_empty()).then(|| Transitions::new(&split.held_out, d, m).one_step());
    let initial_weight = fit.episodes() as f64 / fit.len() as f64;
    let initial_rows = fit.episodes().min(INITIAL_ROWS_PER_BATCH) as i64;
    let jitter_std = model.state_std() * (train.state_noise * rms_step);
    let jitter = |states: Tensor| match train.state_noise > 0.0 {
        true => {
            let noise = model.to_observation_step(&states, states.randn_like() * &jitter_std);
            states + noise
        }
        false => states,
    };
    let max_steps = match train.arrival > 0.0 {
        true => fit.longest().max(train.horizon),
        false => train.horizon,
    };
    let loss = |batch: &Tensor| {
        let mut pairs = fit.draw(batch, train.horizon, train.arrival);
        // An unbiased estimate of the initial term's mean from a few episodes: all of
        // them would cost as much as the transitions (pouring: 176 starts per batch of 256).
        let episodes = Tensor::randint(fit.episodes() as i64, [initial_rows], tch::kind::INT64_CPU);
        pairs.prev = jitter(pairs.prev);
        pairs.next = jitter(pairs.next);
        let (transitions, initial) = model.log_densities(
            &pairs,
            max_steps,
            &fit.initial.index_select(0, &episodes),
            &fit.initial_context.index_select(0, &episodes),
        );
        -(transitions.mean(Kind::Double) + initial.mean(Kind::Double) * initial_weight)
    };
    // The held-out episodes' one-step negative log-likelihood per transition.
    let validation = || {
        check.as_ref().map(|check| {
            let none = |t: &Tensor| t.narrow(0, 0, 0);
            let (transitions, _) =
                model.log_densities(check, 1, &none(&check.prev), &none(&check.context));
            -mean_value(&transitions)
        })
    };
    let split = split.recorded();
    let snapshot = Snapshot {
        config: &config,
        var_store: &vs,
        split: &split,
    };
    let (history, best_epoch) = optimise(&vs, fit.len(), &train.optim, loss, validation, |p| {
        progress(p, &snapshot)
    })?;
    Ok(TrainedFlow {
        config,
        var_store: vs,
        model,
        history,
        best_epoch,
        split,
    })
}

/// Trains like [`train_flow`], keeping the checkpoint in `dir` current as it goes: every
/// epoch that improves is written there at once (an interrupted run keeps its best so far),
/// and at the end the parameters kept, if the last ones written were not those (with
/// [`Keep::Last`](crate::Keep::Last)). `written` is called after each write with the
/// figures of the epoch now on disk (to publish it, say); `progress` once per epoch. A
/// `dir` that cannot be a directory is refused first ([`check_checkpoint_dir`]).
pub fn train_flow_into(
    dir: &Path,
    data: &Demonstrations,
    train: &TrainConfig,
    mut progress: impl FnMut(&Progress),
    mut written: impl FnMut(&Progress),
) -> TrainResult<TrainedFlow> {
    check_checkpoint_dir(dir)?;
    // The epoch on disk, or the write that failed (training stops writing after one).
    let mut on_disk = Ok(0);
    let trained = train_flow(data, train, |p, snapshot| {
        progress(p);
        if p.improved && on_disk.is_ok() {
            on_disk = snapshot.save(dir).map(|()| p.epoch);
            if on_disk.is_ok() {
                written(p);
            }
        }
    })?;
    if on_disk? != trained.best_epoch {
        trained.save(dir)?;
        let kept = trained.history.get(trained.best_epoch.wrapping_sub(1));
        written(kept.ok_or(TrainError::InvalidConfig("training ran no epoch".into()))?);
    }
    Ok(trained)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Contexts, Episode};
    use ciflow_engine::flow::{ContextSet, LatentKind};

    fn config() -> TrainConfig {
        TrainConfig::new("test", LatentKind::LimitCycle)
    }

    fn refusal(train: &TrainConfig) -> String {
        match check_config(train) {
            Err(TrainError::InvalidConfig(problem)) => problem,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn thread_counts_libtorch_cannot_run_are_refused() {
        for threads in [1, MAX_THREADS] {
            check_config(&TrainConfig {
                threads,
                ..config()
            })
            .unwrap();
        }
        for threads in [0, -1, 100_000] {
            assert_eq!(
                refusal(&TrainConfig {
                    threads,
                    ..config()
                }),
                format!("threads must be between 1 and 1024, not {threads}")
            );
        }
    }

    #[test]
    fn arrival_is_a_share() {
        for arrival in [0.0, 0.25, 1.0] {
            check_config(&TrainConfig {
                arrival,
                ..config()
            })
            .unwrap();
        }
        for arrival in [1.5, -1.0, f64::NAN, f64::INFINITY] {
            assert!(
                refusal(&TrainConfig {
                    arrival,
                    ..config()
                })
                .contains("arrival is a share of the training pairs"),
                "{arrival}"
            );
        }
    }

    /// A set reaching past a 1-D context is refused before the context's statistics are
    /// pooled over it (which would index out of the context).
    #[test]
    fn context_sets_past_the_context_are_refused_before_the_data_is_read() {
        let states = (0..5).map(|t| vec![t as f64, 1.0]).collect();
        let data = Demonstrations {
            episodes: vec![Episode::new(states, Contexts::PerEpisode(vec![0.5]))],
            dt: 0.01,
        };
        let train = TrainConfig {
            context_sets: vec![ContextSet {
                start: 0,
                count: 5,
                size: 3,
            }],
            ..config()
        };
        let error = flow_config(&data, &train).unwrap_err();
        assert!(
            error.to_string().contains("within the 1-D context"),
            "{error}"
        );
    }

    #[test]
    fn a_checkpoint_directory_cannot_be_a_file() {
        let dir =
            std::env::temp_dir().join(format!("ciflow-checkpoint-dir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        check_checkpoint_dir(&dir.join("new").join("checkpoint")).unwrap();
        let file = dir.join("file");
        std::fs::write(&file, "a user's file").unwrap();
        for taken in [file.clone(), file.join("checkpoint")] {
            assert!(
                matches!(check_checkpoint_dir(&taken), Err(TrainError::NotADirectory { path }) if path == file)
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
