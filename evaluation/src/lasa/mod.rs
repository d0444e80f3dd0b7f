//! The LASA handwriting benchmark's scoring: a stable flow and the unconstrained
//! behaviour-cloning baseline, each rolled out noise-free from every demonstration's
//! start in observation space (mm) for as many steps as the demonstration has, scored
//! with [`metrics`] (DTW distance, swept error area, final-point error) beside their
//! training figures, and reported as a table, a CSV and plot data. `ciflow lasa` trains
//! the models and calls this module.

pub mod metrics;

use std::fmt::Write as _;

use ciflow_engine::flow::{FlowResult, MeanDynamics};
use ciflow_envs::lasa::Shape;
use serde::Serialize;
use serde_json::json;

use crate::field::{linspace, velocity_grid};
use crate::rollout::mean_rollout;
use metrics::{Point, dtw_distance, final_point_error, swept_error_area};

/// The goal `g` is the context (the origin in the dataset), as in `ciflow/Lasa-v0`.
pub const GOAL: [f64; 2] = [0.0, 0.0];
/// DTW compares every this many samples of the reproduction and the demonstration (100
/// points of LASA's 1000), as the published LASA comparisons do.
const DTW_STRIDE: usize = 10;
/// Every this many samples of a path go to the plot files.
const PLOT_STRIDE: usize = 5;
/// Vector-field grid points per axis in the plot files.
const FIELD_GRID: usize = 25;
/// The field grid covers the demonstrations' box widened by this fraction per side.
const FIELD_MARGIN: f64 = 0.15;

/// The two models compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    Flow,
    Baseline,
}

impl Model {
    pub const ALL: [Model; 2] = [Model::Flow, Model::Baseline];

    pub fn name(self) -> &'static str {
        match self {
            Model::Flow => "flow",
            Model::Baseline => "baseline",
        }
    }
}

/// One model's scores on one shape, averaged over its demonstrations.
#[derive(Clone, Debug, Serialize)]
pub struct Scores {
    /// Mean DTW distance per demonstration sample, mm.
    pub dtw: f64,
    /// Mean swept error area, mm².
    pub swept_area: f64,
    /// Mean final-point error, mm.
    pub final_error: f64,
    /// Training wall-clock time, s.
    pub train_seconds: f64,
    /// The epoch whose parameters were kept.
    pub best_epoch: usize,
    /// Epochs run before early stopping (or the budget).
    pub epochs_run: usize,
    /// The last epoch's validation score (flow: one-step NLL per transition; baseline: MSE).
    pub validation: f64,
}

/// A trained model with the figures of its training run.
pub struct Trained<M> {
    pub model: M,
    pub seconds: f64,
    pub best_epoch: usize,
    pub epochs_run: usize,
    pub validation: f64,
}

/// The mean of `values` (NaN for none).
pub fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    sum / n as f64
}

/// The desired velocity `ẏ(y, g)` on a grid: `(xs, ys, u[j][i], v[j][i])` at `(xs[i], ys[j])`.
fn vector_field<M: MeanDynamics>(model: &M, shape: &Shape) -> FlowResult<serde_json::Value> {
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
        linspace(lo[k] - margin, hi[k] + margin, FIELD_GRID)
    };
    let (xs, ys) = (axis(0), axis(1));
    let [u, v] = velocity_grid(model, &xs, &ys, &GOAL, &mut model.workspace())?;
    Ok(json!({"x": xs, "y": ys, "u": u, "v": v}))
}

/// Every `PLOT_STRIDE`-th point of a path and its last, finite ones only.
pub fn thinned(path: &[Point]) -> Vec<Point> {
    let mut kept: Vec<Point> = path.iter().step_by(PLOT_STRIDE).copied().collect();
    if let Some(last) = path.last()
        && !(path.len() - 1).is_multiple_of(PLOT_STRIDE)
    {
        kept.push(*last);
    }
    kept.retain(|p| p.iter().all(|v| v.is_finite()));
    kept
}

/// Scores `trained` on every demonstration of `shape`: noise-free rollouts from each
/// demonstration's start, as many states as the demonstration has. Returns the scores and
/// the plot data (thinned rollouts and the vector field).
pub fn evaluate<M: MeanDynamics>(
    trained: &Trained<M>,
    shape: &Shape,
) -> FlowResult<(Scores, serde_json::Value)> {
    let mut ws = trained.model.workspace();
    let mut rollouts = Vec::new();
    let (mut dtw, mut area, mut final_error) = (Vec::new(), Vec::new(), Vec::new());
    for demo in &shape.demos {
        let steps = demo.positions.len() - 1;
        let reproduction = mean_rollout(&trained.model, demo.positions[0], &GOAL, steps, &mut ws)?;
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

/// One shape's results: scores per model, in [`Model::ALL`]'s order.
#[derive(Clone)]
pub struct ShapeResult {
    pub name: String,
    pub scores: [Scores; 2],
}

/// The plot data of one shape: its demonstrations and each model's rollouts and field
/// (`bench/lasa_plot.py` draws them).
pub fn shape_plot(
    shape: &Shape,
    flow: serde_json::Value,
    baseline: serde_json::Value,
) -> serde_json::Value {
    let demos: Vec<Vec<Point>> = shape.demos.iter().map(|d| thinned(&d.positions)).collect();
    json!({
        "shape": shape.name,
        "dt": shape.dt,
        "goal": GOAL,
        "demos": demos,
        "flow": flow,
        "baseline": baseline,
    })
}

/// One row per shape and model.
pub fn csv(results: &[ShapeResult]) -> String {
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
pub fn cell(value: f64, decimals: usize) -> String {
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

/// How each score is measured, for the reports.
pub const METRICS: &str = "Reproductions are noise-free rollouts in observation space (mm) \
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

/// The benchmark's report: `settings` (how both models were trained), a table per shape
/// and the mean, the metrics' definitions and the run's verdicts (`summary`).
pub fn markdown(results: &[ShapeResult], settings: &str, total_seconds: f64) -> String {
    let mut text = format!(
        "# LASA handwriting benchmark\n\n{}\n{} shapes in {:.0} s.\n\n{METRICS}\n\
         | shape | DTW flow | DTW BC | SEA flow | SEA BC | final flow | final BC | time flow | time BC |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        settings,
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
