//! `ciflow lasa`: the LASA handwriting benchmark. For each shape it trains a stable C-IFlow
//! (go-to latent, the goal as context) and, with the same budget in the same run, the
//! unconstrained MLP behaviour-cloning baseline; rolls both out noise-free from every
//! demonstration's start, in observation space (mm), for as many steps as the
//! demonstration has; and scores the reproductions ([`metrics`]): DTW distance, swept
//! error area and final-point error, with the training time.
//!
//! Writes `<out>/lasa.md` (a table per shape and the mean), `<out>/lasa.csv` (one row per
//! shape and model), the checkpoints `<out>/checkpoints/<shape>/{flow,baseline}` and, from
//! `bench/lasa_plot.py` (matplotlib, run with the project's Python), PNGs of demos,
//! rollouts and vector fields: `<out>/plots/<shape>.png` and the overview `<out>/lasa.png`.

pub mod metrics;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use ciflow_engine::flow::stability::MeanDynamics;
use ciflow_engine::flow::{BehaviourCloning, Goal, Policy};
use ciflow_envs::lasa::{self, Shape};
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, OptimConfig, Progress, TrainConfig,
    train_baseline, train_flow,
};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde_json::json;

use super::train::ModelArgs;
use metrics::{Point, dtw_distance, final_point_error, swept_error_area};

pub mod ablation;

/// The plotting script, embedded so the command runs from any directory.
const PLOT_SCRIPT: &str = include_str!("../../bench/lasa_plot.py");
/// The task name recorded in the checkpoints: they drive `ciflow/Lasa-v0`.
const TASK: &str = "lasa";
/// The goal `g` is the context (the origin in the dataset), as in `ciflow/Lasa-v0`.
const GOAL: [f64; 2] = [0.0, 0.0];
/// DTW compares every this many samples of the reproduction and the demonstration (100
/// points of LASA's 1000), as the published LASA comparisons do.
const DTW_STRIDE: usize = 10;
/// Every this many samples of a path go to the plot files.
const PLOT_STRIDE: usize = 5;
/// Vector-field grid points per axis in the plot files.
const FIELD_GRID: usize = 25;
/// The field grid covers the demonstrations' box widened by this fraction per side.
const FIELD_MARGIN: f64 = 0.15;

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

/// The two models compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Model {
    Flow,
    Baseline,
}

impl Model {
    const ALL: [Model; 2] = [Model::Flow, Model::Baseline];

    fn name(self) -> &'static str {
        match self {
            Model::Flow => "flow",
            Model::Baseline => "baseline",
        }
    }
}

/// One model's scores on one shape, averaged over its demonstrations.
#[derive(Clone, Debug, Serialize)]
struct Scores {
    /// Mean DTW distance per demonstration sample, mm.
    dtw: f64,
    /// Mean swept error area, mm².
    swept_area: f64,
    /// Mean final-point error, mm.
    final_error: f64,
    /// Training wall-clock time, s.
    train_seconds: f64,
    /// The epoch whose parameters were kept.
    best_epoch: usize,
    /// Epochs run before early stopping (or the budget).
    epochs_run: usize,
    /// The last epoch's validation score (flow: one-step NLL per transition; baseline: MSE).
    validation: f64,
}

/// A trained model with the figures of its training run.
struct Trained<M> {
    model: M,
    seconds: f64,
    best_epoch: usize,
    epochs_run: usize,
    validation: f64,
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

/// The noise-free rollout `y_{k+1} = F(y_k, g)` from `start`, `steps` points long; it
/// stops at the first non-finite point (kept, so the metrics see the failure).
fn rollout<M: MeanDynamics>(model: &M, start: Point, steps: usize) -> anyhow::Result<Vec<Point>> {
    let mut ws = model.workspace();
    let mut path = Vec::with_capacity(steps);
    let (mut y, mut next) = (start.to_vec(), vec![0.0; 2]);
    path.push(start);
    while path.len() < steps {
        model.mean_next(&y, &GOAL, &mut ws, &mut next)?;
        path.push([next[0], next[1]]);
        if next.iter().any(|v| !v.is_finite()) {
            break;
        }
        std::mem::swap(&mut y, &mut next);
    }
    Ok(path)
}

fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    sum / n as f64
}

/// The field `(F(y, g) − y) / dt` on a grid: `(xs, ys, u[j][i], v[j][i])` at `(xs[i], ys[j])`.
fn vector_field<M: MeanDynamics>(model: &M, shape: &Shape) -> anyhow::Result<serde_json::Value> {
    let points = || shape.demos.iter().flat_map(|d| d.positions.iter());
    let (mut lo, mut hi) = ([GOAL[0], GOAL[1]], [GOAL[0], GOAL[1]]);
    for p in points() {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let axis = |k: usize| -> Vec<f64> {
        let margin = FIELD_MARGIN * (hi[k] - lo[k]);
        let (a, b) = (lo[k] - margin, hi[k] + margin);
        (0..FIELD_GRID)
            .map(|i| a + (b - a) * i as f64 / (FIELD_GRID - 1) as f64)
            .collect()
    };
    let (xs, ys) = (axis(0), axis(1));
    let mut ws = model.workspace();
    let mut next = vec![0.0; 2];
    let (mut u, mut v) = (Vec::new(), Vec::new());
    for &y in &ys {
        let (mut row_u, mut row_v) = (Vec::new(), Vec::new());
        for &x in &xs {
            model.mean_next(&[x, y], &GOAL, &mut ws, &mut next)?;
            row_u.push((next[0] - x) / shape.dt);
            row_v.push((next[1] - y) / shape.dt);
        }
        u.push(row_u);
        v.push(row_v);
    }
    Ok(json!({"x": xs, "y": ys, "u": u, "v": v}))
}

/// Every [`PLOT_STRIDE`]-th point of a path and its last, finite ones only.
fn thinned(path: &[Point]) -> Vec<Point> {
    let mut kept: Vec<Point> = path.iter().step_by(PLOT_STRIDE).copied().collect();
    if let Some(last) = path.last()
        && !(path.len() - 1).is_multiple_of(PLOT_STRIDE)
    {
        kept.push(*last);
    }
    kept.retain(|p| p.iter().all(|v| v.is_finite()));
    kept
}

/// Scores `model` on every demonstration of `shape`; returns the scores and plot data.
fn evaluate<M: MeanDynamics>(
    trained: &Trained<M>,
    shape: &Shape,
) -> anyhow::Result<(Scores, serde_json::Value)> {
    let mut rollouts = Vec::new();
    let (mut dtw, mut area, mut final_error) = (Vec::new(), Vec::new(), Vec::new());
    for demo in &shape.demos {
        let reproduction = rollout(&trained.model, demo.positions[0], demo.positions.len())?;
        let every = |path: &[Point]| path.iter().step_by(DTW_STRIDE).copied().collect::<Vec<_>>();
        dtw.push(dtw_distance(&every(&reproduction), &every(&demo.positions)));
        // A rollout cut short by a non-finite point has no time-aligned partner left.
        let complete = reproduction.len() == demo.positions.len();
        area.push(match complete {
            true => swept_error_area(&reproduction, &demo.positions),
            false => f64::INFINITY,
        });
        final_error.push(final_point_error(&reproduction, &demo.positions));
        rollouts.push(thinned(&reproduction));
    }
    let scores = Scores {
        dtw: mean(dtw.into_iter()),
        swept_area: mean(area.into_iter()),
        final_error: mean(final_error.into_iter()),
        train_seconds: trained.seconds,
        best_epoch: trained.best_epoch,
        epochs_run: trained.epochs_run,
        validation: trained.validation,
    };
    let plot = json!({
        "rollouts": rollouts,
        "field": vector_field(&trained.model, shape)?,
    });
    Ok((scores, plot))
}

/// One bar over every epoch of the run; each model advances it by its budget.
struct RunProgress {
    bar: ProgressBar,
    done: u64,
}

impl RunProgress {
    /// A bar over `epochs`, every model's budget added up.
    fn new(epochs: usize) -> Self {
        let bar = ProgressBar::new(epochs as u64);
        bar.set_style(
            ProgressStyle::with_template("lasa [{bar:30}] {percent}% {msg} ({elapsed}, eta {eta})")
                .expect("valid template")
                .progress_chars("=> "),
        );
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

/// One shape's results: scores per model, in [`Model::ALL`]'s order.
#[derive(Clone)]
struct ShapeResult {
    name: String,
    scores: [Scores; 2],
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
    let demos: Vec<Vec<Point>> = shape.demos.iter().map(|d| thinned(&d.positions)).collect();
    let plot = json!({
        "shape": name,
        "dt": shape.dt,
        "goal": GOAL,
        "demos": demos,
        "flow": flow_plot,
        "baseline": baseline_plot,
    });
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

fn csv(results: &[ShapeResult]) -> String {
    let mut text = String::from(
        "shape,model,dtw_mm,swept_area_mm2,final_error_mm,train_seconds,best_epoch,epochs_run,validation\n",
    );
    for result in results {
        for (model, s) in Model::ALL.iter().zip(&result.scores) {
            writeln!(
                text,
                "{},{},{},{},{},{:.3},{},{},{}",
                result.name,
                model.name(),
                s.dtw,
                s.swept_area,
                s.final_error,
                s.train_seconds,
                s.best_epoch,
                s.epochs_run,
                s.validation
            )
            .expect("writing to a String");
        }
    }
    text
}

/// `value` with `decimals` decimals; `∞` for a failed reproduction.
fn cell(value: f64, decimals: usize) -> String {
    if value.is_finite() {
        format!("{value:.decimals$}")
    } else {
        "∞".into()
    }
}

fn table_row(label: &str, [flow, baseline]: [&Scores; 2]) -> String {
    format!(
        "| {label} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
        cell(flow.dtw, 2),
        cell(baseline.dtw, 2),
        cell(flow.swept_area, 0),
        cell(baseline.swept_area, 0),
        cell(flow.final_error, 2),
        cell(baseline.final_error, 2),
        cell(flow.train_seconds, 2),
        cell(baseline.train_seconds, 2),
    )
}

/// The mean over shapes of each model's scores.
fn mean_scores(results: &[ShapeResult], model: usize) -> Scores {
    let of = |f: fn(&Scores) -> f64| mean(results.iter().map(|r| f(&r.scores[model])));
    Scores {
        dtw: of(|s| s.dtw),
        swept_area: of(|s| s.swept_area),
        final_error: of(|s| s.final_error),
        train_seconds: of(|s| s.train_seconds),
        best_epoch: 0,
        epochs_run: 0,
        validation: f64::NAN,
    }
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

/// How each score is measured, for the reports.
const METRICS: &str = "Reproductions are noise-free rollouts in observation space (mm) \
    from each of a shape's 7 demonstrations' starts, as many steps as the demonstration at \
    the shape's mean sampling period; scores are means over the 7 demonstrations.\n\n\
    - **DTW**: reproduction and demonstration taken at every 10th sample (100 points), \
    dynamic time warping with Euclidean point distance, the accumulated cost divided by \
    the longer length (mm)\n\
    - **SEA**: swept error area between reproduction and demonstration (mm²)\n\
    - **final**: distance between the reproduction's and the demonstration's last points \
    (mm)\n\
    - **time**: training wall-clock (s)\n\
    - ∞: the reproduction left the finite numbers\n";

/// The shapes of the published comparison with ImitationFlow, and its scores on them:
/// mean DTW and final-point error (mm) of the authors' 2020 code (depth-10 affine
/// coupling with LU mixing, tanh latent, 1000 epochs of multi-step windows), measured
/// with this command's metric on a 2-core machine of this project.
pub const REFERENCE_SHAPES: [&str; 6] =
    ["Sshape", "Angle", "CShape", "NShape", "WShape", "Khamesh"];
const IMITATION_FLOW_DTW: f64 = 2.27;
const IMITATION_FLOW_FINAL: f64 = 0.70;

/// The run's verdicts: flow against baseline over every shape and, when the run holds
/// the reference shapes, against ImitationFlow on them.
fn summary(results: &[ShapeResult]) -> String {
    let (flow, baseline) = (mean_scores(results, 0), mean_scores(results, 1));
    let better = results
        .iter()
        .filter(|r| r.scores[0].dtw < r.scores[1].dtw)
        .count();
    let worst = results
        .iter()
        .max_by(|a, b| a.scores[0].final_error.total_cmp(&b.scores[0].final_error))
        .expect("a run has shapes");
    let mut text = format!(
        "\n## Summary\n\n\
         - flow / baseline mean DTW: {} / {} mm = **{}**; the flow is closer on {better} \
         of {} shapes\n\
         - flow final-point error: mean {} mm, worst {} mm ({}); baseline mean {} mm\n\
         - training time per shape: flow {} s, baseline {} s\n",
        cell(flow.dtw, 2),
        cell(baseline.dtw, 2),
        cell(flow.dtw / baseline.dtw, 2),
        results.len(),
        cell(flow.final_error, 2),
        cell(worst.scores[0].final_error, 2),
        worst.name,
        cell(baseline.final_error, 2),
        cell(flow.train_seconds, 1),
        cell(baseline.train_seconds, 1),
    );
    let reference: Vec<ShapeResult> = results
        .iter()
        .filter(|r| REFERENCE_SHAPES.contains(&r.name.as_str()))
        .cloned()
        .collect();
    if reference.len() == REFERENCE_SHAPES.len() {
        let (flow, baseline) = (mean_scores(&reference, 0), mean_scores(&reference, 1));
        text += &format!(
            "- on ImitationFlow's six shapes ({}): mean DTW flow {} mm, baseline {} mm, \
             ImitationFlow {IMITATION_FLOW_DTW} mm (flow / ImitationFlow **{}**); final \
             error flow {} mm, baseline {} mm, ImitationFlow {IMITATION_FLOW_FINAL} mm\n",
            REFERENCE_SHAPES.join(", "),
            cell(flow.dtw, 2),
            cell(baseline.dtw, 2),
            cell(flow.dtw / IMITATION_FLOW_DTW, 2),
            cell(flow.final_error, 2),
            cell(baseline.final_error, 2),
        );
    }
    text
}

fn markdown(results: &[ShapeResult], flow: &TrainConfig, total_seconds: f64) -> String {
    let mut text = format!(
        "# LASA handwriting benchmark\n\n{}\n{} shapes in {:.0} s.\n\n{METRICS}\n\
         | shape | DTW flow | DTW BC | SEA flow | SEA BC | final flow | final BC | time flow | time BC |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        settings(flow),
        results.len(),
        total_seconds,
    );
    for result in results {
        text += &table_row(&result.name, [&result.scores[0], &result.scores[1]]);
    }
    let (flow, baseline) = (mean_scores(results, 0), mean_scores(results, 1));
    text += &table_row("**mean**", [&flow, &baseline]);
    text += &summary(results);
    text
}

/// The project's Python: `CIFLOW_PYTHON`, else the workspace's `.venv`, else `python3`.
fn python() -> String {
    if let Ok(python) = std::env::var("CIFLOW_PYTHON") {
        return python;
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    if venv.exists() {
        venv.to_string_lossy().into_owned()
    } else {
        "python3".into()
    }
}

fn plot(out: &Path) -> anyhow::Result<()> {
    let python = python();
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
    let table = markdown(&results, &config, start.elapsed().as_secs_f64());
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
