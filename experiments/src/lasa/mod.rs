//! The LASA handwriting benchmark. For each shape it trains a stable C-IFlow (the task's
//! recipe for `ciflow/Lasa-v0`: the goal as context) and, in the same run on the same
//! seven demonstrations, the unconstrained MLP behaviour-cloning baseline with settings
//! of its own ([`baseline_config`]: 200 epochs, whatever the flow's options); rolls both
//! out noise-free from every demonstration's start, in observation space (mm), for as many steps as the
//! demonstration has; and scores the reproductions ([`ciflow_evaluation::lasa`]): DTW
//! distance, swept error area and final-point error, with the training time.
//!
//! [`benchmark`] writes `<out>/lasa.md` (a table per shape and the mean), `<out>/lasa.csv`
//! (one row per shape and model), the checkpoints `<out>/checkpoints/<shape>/{flow,baseline}`
//! and the plot data `<out>/plots/<shape>.json`, which [`plot`] draws with
//! `bench/lasa_plot.py` (matplotlib, run with the project's Python) into
//! `<out>/plots/<shape>.png` and the overview `<out>/lasa.png`.

pub mod ablation;

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use ciflow_engine::flow::{BehaviourCloning, Goal, Policy};
use ciflow_envs::lasa::{self, LasaError, Shape};
use ciflow_evaluation::lasa::{
    GOAL, Model, ShapeResult, Trained, csv, evaluate, markdown, shape_plot,
};
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, Keep, OptimConfig, Progress,
    TrainConfig, train_baseline, train_flow,
};

use crate::error::{ExperimentError, ExperimentResult};

/// The plotting script, embedded so that a run draws its plots from any directory.
const PLOT_SCRIPT: &str = include_str!("../../../bench/lasa_plot.py");
/// The task name recorded in the checkpoints: they drive `ciflow/Lasa-v0`.
pub const TASK: &str = "lasa";

/// Where a run stands after an epoch of one of its models.
pub struct RunEpoch<'a> {
    /// Epochs of the run's budget done, every model's counted in full once it finished.
    pub done: u64,
    pub shape: &'a str,
    pub model: Model,
    pub progress: &'a Progress,
}

/// Counts a run's epochs and tells the caller after each.
struct Tally<'f> {
    done: u64,
    on_epoch: &'f mut dyn FnMut(&RunEpoch),
}

impl Tally<'_> {
    fn epoch(&mut self, shape: &str, model: Model, progress: &Progress) {
        (self.on_epoch)(&RunEpoch {
            done: self.done + progress.epoch as u64,
            shape,
            model,
            progress,
        });
    }

    /// A model finished (perhaps early): its whole budget of `epochs` counts as done.
    fn finish_model(&mut self, epochs: usize) {
        self.done += epochs as u64;
    }
}

/// The epochs [`benchmark`] runs at most on `shapes` shapes: each shape's flow and baseline.
pub fn budget(shapes: usize, flow: &TrainConfig) -> u64 {
    (shapes * (flow.optim.epochs + baseline_config(flow).optim.epochs)) as u64
}

/// `requested` (else `default`), checked against the dataset's shapes.
pub fn shape_names(
    requested: Option<Vec<String>>,
    default: Vec<String>,
) -> ExperimentResult<Vec<String>> {
    let names = requested.unwrap_or(default);
    if names.is_empty() {
        return Err(ExperimentError::NoShapes);
    }
    let known = lasa::shape_names()?;
    match names.iter().find(|n| !known.contains(n)) {
        Some(unknown) => Err(LasaError::UnknownShape {
            name: unknown.clone(),
            known: known.join(", "),
        }
        .into()),
        None => Ok(names),
    }
}

/// A shape's demonstrations as the policy sees them: positions, the goal as context,
/// sampled at the shape's mean period.
fn demonstrations(shape: &Shape) -> Demonstrations {
    Demonstrations {
        episodes: shape
            .demos
            .iter()
            .map(|demo| {
                let states = demo.positions.iter().map(|p| p.to_vec()).collect();
                Episode::new(states, Contexts::PerEpisode(GOAL.to_vec()))
            })
            .collect(),
        dt: shape.dt,
    }
}

/// Trains the flow with `config`, writes it to `dir` and loads it back as the engine
/// serves it.
fn train_shape_flow(
    shape: &Shape,
    data: &Demonstrations,
    config: &TrainConfig,
    tally: &mut Tally,
    dir: &Path,
) -> ExperimentResult<Trained<Policy>> {
    let start = Instant::now();
    let trained = train_flow(data, config, |p, _| {
        tally.epoch(&shape.name, Model::Flow, p)
    })
    .map_err(|source| ExperimentError::Training {
        shape: shape.name.clone(),
        model: Model::Flow.name(),
        source,
    })?;
    let seconds = start.elapsed().as_secs_f64();
    trained.save(dir).map_err(|source| saving(dir, source))?;
    tally.finish_model(config.optim.epochs);
    let model = Policy::load(dir, Some(TASK)).map_err(|source| loading(dir, source))?;
    Ok(with_figures(
        model,
        seconds,
        trained.best_epoch,
        &trained.history,
    ))
}

/// The unconstrained baseline's training: its standing settings
/// ([`BaselineTrainConfig::new`]) whatever the flow's recipe says, except that it fits
/// the same demonstrations as the flow, all of them, and keeps the last epoch — with none
/// held out its patience watches the training loss, which has not stalled for that long
/// in any run so far, so it trains its whole budget — and that
/// its seed follows the flow's. With one of the seven held out for early stopping instead,
/// it was further from the demonstrations on 23 of the 30 shapes (README, "LASA
/// handwriting benchmark").
pub fn baseline_config(flow: &TrainConfig) -> BaselineTrainConfig {
    let goal = Goal::ContextIndices {
        indices: flow.goal_context_indices.clone().unwrap_or_default(),
    };
    BaselineTrainConfig {
        validation_fraction: 0.0,
        optim: OptimConfig {
            seed: flow.optim.seed,
            keep: Keep::Last,
            ..OptimConfig::default()
        },
        ..BaselineTrainConfig::new(TASK, goal)
    }
}

/// Trains the unconstrained baseline ([`baseline_config`]).
fn train_shape_baseline(
    shape: &Shape,
    data: &Demonstrations,
    flow: &TrainConfig,
    tally: &mut Tally,
    dir: &Path,
) -> ExperimentResult<Trained<BehaviourCloning>> {
    let config = baseline_config(flow);
    let start = Instant::now();
    let trained = train_baseline(data, &config, |p| {
        tally.epoch(&shape.name, Model::Baseline, p)
    })
    .map_err(|source| ExperimentError::Training {
        shape: shape.name.clone(),
        model: Model::Baseline.name(),
        source,
    })?;
    let seconds = start.elapsed().as_secs_f64();
    trained.save(dir).map_err(|source| saving(dir, source))?;
    tally.finish_model(config.optim.epochs);
    let model = BehaviourCloning::load(dir, Some(TASK)).map_err(|source| loading(dir, source))?;
    Ok(with_figures(
        model,
        seconds,
        trained.best_epoch,
        &trained.history,
    ))
}

/// `model` as loaded back from its checkpoint, with the figures of its training run.
fn with_figures<M>(model: M, seconds: f64, best_epoch: usize, history: &[Progress]) -> Trained<M> {
    Trained {
        model,
        seconds,
        best_epoch,
        epochs_run: history.len(),
        validation: history.last().map_or(f64::NAN, |p| p.validation),
    }
}

fn saving(dir: &Path, source: ciflow_train::TrainError) -> ExperimentError {
    ExperimentError::SaveCheckpoint {
        path: dir.to_owned(),
        source,
    }
}

fn loading(dir: &Path, source: ciflow_engine::flow::FlowError) -> ExperimentError {
    ExperimentError::LoadCheckpoint {
        path: dir.to_owned(),
        source,
    }
}

/// [`evaluate`] with the shape and model named in its error.
fn scored<M: ciflow_engine::flow::MeanDynamics>(
    trained: &Trained<M>,
    shape: &Shape,
    model: Model,
) -> ExperimentResult<(ciflow_evaluation::lasa::Scores, serde_json::Value)> {
    evaluate(trained, shape).map_err(|source| ExperimentError::Scoring {
        shape: shape.name.clone(),
        model: model.name(),
        source,
    })
}

/// Writes `text` to `path`.
fn write(path: &Path, text: &str) -> ExperimentResult<()> {
    std::fs::write(path, text).map_err(|source| ExperimentError::Write {
        path: path.to_owned(),
        source,
    })
}

/// Creates the directory `path`.
fn create_dir(path: &Path) -> ExperimentResult<()> {
    std::fs::create_dir_all(path).map_err(|source| ExperimentError::Write {
        path: path.to_owned(),
        source,
    })
}

fn run_shape(
    name: &str,
    config: &TrainConfig,
    out: &Path,
    tally: &mut Tally,
) -> ExperimentResult<ShapeResult> {
    let shape = lasa::load(name)?;
    let data = demonstrations(&shape);
    let checkpoints = out.join("checkpoints").join(name);
    let flow = train_shape_flow(
        &shape,
        &data,
        config,
        tally,
        &checkpoints.join(Model::Flow.name()),
    )?;
    let (flow_scores, flow_plot) = scored(&flow, &shape, Model::Flow)?;
    let baseline_dir = checkpoints.join(Model::Baseline.name());
    let baseline = train_shape_baseline(&shape, &data, config, tally, &baseline_dir)?;
    let (baseline_scores, baseline_plot) = scored(&baseline, &shape, Model::Baseline)?;
    let plot = shape_plot(&shape, flow_plot, baseline_plot);
    let plots = out.join("plots");
    create_dir(&plots)?;
    write(
        &plots.join(format!("{name}.json")),
        &serde_json::to_string(&plot)?,
    )?;
    Ok(ShapeResult {
        name: name.to_owned(),
        scores: [flow_scores, baseline_scores],
    })
}

/// The training settings of both models, as the reports state them.
fn settings(flow: &TrainConfig) -> String {
    let baseline = baseline_config(flow);
    let optim = &flow.optim;
    format!(
        "Stable C-IFlow: {:?} latent (min rate {} /s), {} × {:?} coupling, conditioners \
         {:?}, spans of up to {} steps, state jitter {} × RMS step, {:.0}% of the \
         demonstrations held out, {} epochs (keep {:?}, patience {}), batch {}, learning \
         rate {}, seed {}; the goal as context. Unconstrained MLP behaviour-cloning \
         baseline: hidden {:?}, {:.0}% of the demonstrations held out, {} epochs (keep \
         {:?}). Both trained in the same run, one libtorch thread each.",
        flow.latent,
        flow.min_rate,
        flow.layers,
        flow.coupling,
        flow.hidden,
        flow.horizon,
        flow.state_noise,
        100.0 * flow.validation_fraction,
        optim.epochs,
        optim.keep,
        optim.patience,
        optim.batch_size,
        optim.learning_rate,
        optim.seed,
        baseline.hidden,
        100.0 * baseline.validation_fraction,
        baseline.optim.epochs,
        baseline.optim.keep,
    )
}

/// What [`benchmark`] writes into its directory.
const RUN_OUTPUTS: [&str; 5] = ["lasa.md", "lasa.csv", "lasa.png", "checkpoints", "plots"];

/// Removes an earlier run's `outputs` from `out` when `overwrite`, and refuses them
/// otherwise: a run on other shapes would leave the earlier shapes' checkpoints and plots
/// beside a table without them. Anything else in `out` stays.
fn clear_earlier_run(out: &Path, outputs: &[&str], overwrite: bool) -> ExperimentResult<()> {
    let earlier: Vec<_> = outputs
        .iter()
        .map(|name| out.join(name))
        .filter(|path| path.exists())
        .collect();
    if !earlier.is_empty() && !overwrite {
        return Err(ExperimentError::EarlierRun {
            path: out.to_owned(),
            outputs: outputs.join(", "),
        });
    }
    for path in earlier {
        match path.is_dir() {
            true => std::fs::remove_dir_all(&path),
            false => std::fs::remove_file(&path),
        }
        .map_err(|source| ExperimentError::Write { path, source })?;
    }
    Ok(())
}

/// Runs the benchmark on the shapes `names` with the flow's `config` into `out` (an
/// earlier run's results there are replaced only when `overwrite`), telling `on_epoch`
/// after every epoch; returns the table it wrote to `lasa.md`.
pub fn benchmark(
    names: &[String],
    config: &TrainConfig,
    out: &Path,
    overwrite: bool,
    mut on_epoch: impl FnMut(&RunEpoch),
) -> ExperimentResult<String> {
    let start = Instant::now();
    clear_earlier_run(out, &RUN_OUTPUTS, overwrite)?;
    create_dir(out)?;
    let mut tally = Tally {
        done: 0,
        on_epoch: &mut on_epoch,
    };
    let results = names
        .iter()
        .map(|name| run_shape(name, config, out, &mut tally))
        .collect::<ExperimentResult<Vec<_>>>()?;
    let table = markdown(&results, &settings(config), start.elapsed().as_secs_f64());
    write(&out.join("lasa.md"), &table)?;
    write(&out.join("lasa.csv"), &csv(&results))?;
    Ok(table)
}

/// Draws the plots of the run in `out` with the project's Python.
pub fn plot(out: &Path) -> ExperimentResult<()> {
    let python = ciflow_envs::python::interpreter();
    let output = Command::new(&python)
        .arg("-c")
        .arg(PLOT_SCRIPT)
        .arg(out)
        .output()
        .map_err(|source| ExperimentError::PlotLaunch {
            python: python.clone(),
            source,
        })?;
    match output.status.success() {
        true => Ok(()),
        false => Err(ExperimentError::Plot {
            python,
            stderr: String::from_utf8_lossy(&output.stderr).into_owned(),
        }),
    }
}
