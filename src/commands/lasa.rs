//! `ciflow lasa`: the LASA handwriting benchmark. For each shape it trains a stable C-IFlow
//! (go-to latent, the goal as context) and, with the same budget in the same run, the
//! unconstrained MLP behaviour-cloning baseline; rolls both out noise-free from every
//! demonstration's start, in observation space (mm), for as many steps as the
//! demonstration has; and scores the reproductions (`ciflow_evaluation::lasa`): DTW
//! distance, swept error area and final-point error, with the training time.
//!
//! Writes `<out>/lasa.md` (a table per shape and the mean), `<out>/lasa.csv` (one row per
//! shape and model), the checkpoints `<out>/checkpoints/<shape>/{flow,baseline}` and, from
//! `bench/lasa_plot.py` (matplotlib, run with the project's Python), PNGs of demos,
//! rollouts and vector fields: `<out>/plots/<shape>.png` and the overview `<out>/lasa.png`.

pub mod ablation;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use ciflow_engine::flow::{BehaviourCloning, Goal, Policy};
use ciflow_envs::lasa::{self, Shape};
use ciflow_evaluation::lasa::{
    GOAL, Model, REFERENCE_SHAPES, ShapeResult, Trained, csv, evaluate, markdown, shape_plot,
};
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, OptimConfig, Progress, TrainConfig,
    train_baseline, train_flow,
};
use indicatif::ProgressBar;

use super::train::ModelArgs;
use crate::progress;

/// The plotting script, embedded so the command runs from any directory.
const PLOT_SCRIPT: &str = include_str!("../../bench/lasa_plot.py");
/// The task name recorded in the checkpoints: they drive `ciflow/Lasa-v0`.
const TASK: &str = "lasa";

#[derive(clap::Args, Debug)]
pub struct LasaArgs {
    /// Shapes to run, comma-separated (default: all 30).
    #[arg(long, value_delimiter = ',')]
    pub shapes: Option<Vec<String>>,
    /// Output directory (lasa.md, lasa.csv, checkpoints/, plots/, lasa.png).
    #[arg(long)]
    pub out: PathBuf,
    /// Skip the PNG plots (they need Python with matplotlib).
    #[arg(long)]
    pub no_plots: bool,
    /// Instead of the benchmark, measure what each of the default recipe's choices buys:
    /// the flow retrained with one setting changed at a time, on the shapes given
    /// (default: the six of ImitationFlow's comparison), into `<out>/ablation.md`.
    #[arg(long)]
    pub ablation: bool,
    #[command(flatten)]
    pub model: ModelArgs,
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

/// One bar over every epoch of the run; each model advances it by its budget.
struct RunProgress {
    bar: ProgressBar,
    done: u64,
}

impl RunProgress {
    /// A bar over `epochs`, every model's budget added up.
    fn new(epochs: usize) -> Self {
        let bar = progress::bar(epochs as u64, "lasa", "epochs");
        Self { bar, done: 0 }
    }

    fn epoch(&self, shape: &str, model: Model, p: &Progress) {
        self.bar.set_position(self.done + p.epoch as u64);
        self.bar.set_message(format!(
            "{shape} {}: epoch {}/{} validation {:.3}",
            model.name(),
            p.epoch,
            p.epochs,
            p.validation
        ));
    }

    /// A model finished (perhaps early): its whole budget of `epochs` counts as done.
    fn finish_model(&mut self, epochs: usize) {
        self.done += epochs as u64;
        self.bar.set_position(self.done);
    }
}

/// The flow's configuration: `ciflow train`'s for `ciflow/Lasa-v0` (the task's recipe,
/// the goal as context) with the command line's settings.
fn flow_config(args: &ModelArgs) -> anyhow::Result<TrainConfig> {
    let task = ciflow_envs::registry::entry(TASK)?;
    args.flow(task.training_recipe(GOAL.len())?)
}

fn train_shape_flow(
    shape: &Shape,
    data: &Demonstrations,
    config: &TrainConfig,
    progress: &RunProgress,
    dir: &Path,
) -> anyhow::Result<Trained<Policy>> {
    let start = Instant::now();
    let trained = train_flow(data, config, |p, _| {
        progress.epoch(&shape.name, Model::Flow, p)
    })
    .with_context(|| format!("training the flow on {}", shape.name))?;
    let seconds = start.elapsed().as_secs_f64();
    trained
        .save(dir)
        .with_context(|| format!("writing {}", dir.display()))?;
    Ok(Trained {
        model: Policy::load(dir, Some(TASK))?,
        seconds,
        best_epoch: trained.best_epoch,
        epochs_run: trained.history.len(),
        validation: trained.history.last().map_or(f64::NAN, |p| p.validation),
    })
}

/// Trains the unconstrained baseline. The control keeps its standing settings
/// ([`BaselineTrainConfig::new`]) whatever the flow's recipe or flags say; only the seed
/// follows the run's.
fn train_shape_baseline(
    shape: &Shape,
    data: &Demonstrations,
    flow: &TrainConfig,
    progress: &RunProgress,
    dir: &Path,
) -> anyhow::Result<Trained<BehaviourCloning>> {
    let goal = Goal::ContextIndices {
        indices: flow.goal_context_indices.clone().unwrap_or_default(),
    };
    let config = BaselineTrainConfig {
        optim: OptimConfig {
            seed: flow.optim.seed,
            ..OptimConfig::default()
        },
        ..BaselineTrainConfig::new(TASK, goal)
    };
    let start = Instant::now();
    let trained = train_baseline(data, &config, |p| {
        progress.epoch(&shape.name, Model::Baseline, p)
    })
    .with_context(|| format!("training the baseline on {}", shape.name))?;
    let seconds = start.elapsed().as_secs_f64();
    trained
        .save(dir)
        .with_context(|| format!("writing {}", dir.display()))?;
    Ok(Trained {
        model: BehaviourCloning::load(dir, Some(TASK))?,
        seconds,
        best_epoch: trained.best_epoch,
        epochs_run: trained.history.len(),
        validation: trained.history.last().map_or(f64::NAN, |p| p.validation),
    })
}

fn run_shape(
    name: &str,
    config: &TrainConfig,
    out: &Path,
    progress: &mut RunProgress,
) -> anyhow::Result<ShapeResult> {
    let shape = lasa::load(name)?;
    let data = demonstrations(&shape);
    let checkpoints = out.join("checkpoints").join(name);
    let flow = train_shape_flow(
        &shape,
        &data,
        config,
        progress,
        &checkpoints.join(Model::Flow.name()),
    )?;
    progress.finish_model(config.optim.epochs);
    let (flow_scores, flow_plot) = evaluate(&flow, &shape)?;
    let baseline = train_shape_baseline(
        &shape,
        &data,
        config,
        progress,
        &checkpoints.join(Model::Baseline.name()),
    )?;
    progress.finish_model(OptimConfig::default().epochs);
    let (baseline_scores, baseline_plot) = evaluate(&baseline, &shape)?;
    let plot = shape_plot(&shape, flow_plot, baseline_plot);
    let plots = out.join("plots");
    std::fs::create_dir_all(&plots)?;
    let path = plots.join(format!("{name}.json"));
    std::fs::write(&path, serde_json::to_string(&plot)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(ShapeResult {
        name: name.to_owned(),
        scores: [flow_scores, baseline_scores],
    })
}

/// The training settings of both models, as the reports state them.
fn settings(flow: &TrainConfig) -> String {
    let baseline = BaselineTrainConfig::new(
        TASK,
        Goal::ContextIndices {
            indices: Vec::new(),
        },
    );
    let optim = &flow.optim;
    format!(
        "Stable C-IFlow: {:?} latent (min rate {} /s), {} × {:?} coupling, conditioners \
         {:?}, spans of up to {} steps, state jitter {} × RMS step, {:.0}% of the \
         demonstrations held out, {} epochs (keep {:?}, patience {}), batch {}, learning \
         rate {}, seed {}; the goal as context. Unconstrained MLP behaviour-cloning \
         baseline: its standing settings, hidden {:?}, {:.0}% held out for early stopping, \
         at most {} epochs (patience {}). Both trained in the same run, one libtorch \
         thread each.",
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
        baseline.optim.patience,
    )
}

fn plot(out: &Path) -> anyhow::Result<()> {
    let python = lasa::python();
    let output = Command::new(&python)
        .arg("-c")
        .arg(PLOT_SCRIPT)
        .arg(out)
        .output()
        .with_context(|| format!("running {python}"))?;
    anyhow::ensure!(
        output.status.success(),
        "plotting with {python} failed (pass --no-plots to skip): {}",
        String::from_utf8_lossy(&output.stderr)
    );
    Ok(())
}

/// The shapes named on the command line, checked against the dataset's, else `default`.
fn shape_names(args: &LasaArgs, default: Vec<String>) -> anyhow::Result<Vec<String>> {
    let names = args.shapes.clone().unwrap_or(default);
    anyhow::ensure!(!names.is_empty(), "--shapes names no shape");
    let known = lasa::shape_names()?;
    if let Some(unknown) = names.iter().find(|n| !known.contains(n)) {
        anyhow::bail!(
            "unknown LASA shape `{unknown}`; known: {}",
            known.join(", ")
        );
    }
    Ok(names)
}

pub fn run(args: LasaArgs) -> anyhow::Result<()> {
    let config = flow_config(&args.model)?;
    let names = match args.ablation {
        true => shape_names(&args, REFERENCE_SHAPES.map(String::from).to_vec())?,
        false => shape_names(&args, lasa::shape_names()?)?,
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    if args.ablation {
        return ablation::run(&names, &config, &args.out);
    }
    let start = Instant::now();
    let budget = config.optim.epochs + OptimConfig::default().epochs;
    let mut progress = RunProgress::new(names.len() * budget);
    let results = names
        .iter()
        .map(|name| run_shape(name, &config, &args.out, &mut progress))
        .collect::<anyhow::Result<Vec<_>>>()?;
    progress.bar.finish_and_clear();
    let table = markdown(&results, &settings(&config), start.elapsed().as_secs_f64());
    for (file, text) in [("lasa.md", &table), ("lasa.csv", &csv(&results))] {
        let path = args.out.join(file);
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if !args.no_plots {
        plot(&args.out)?;
    }
    println!("{table}");
    println!("wrote {}", args.out.display());
    Ok(())
}
