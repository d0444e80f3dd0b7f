//! Figure data of a 2-D flow policy, per context `c`:
//!
//! - the learned vector field `ẏ_des = J_f(z) v(z)`, `z = f⁻¹(y, c)`, noise-free
//!   ([`Policy::velocity`]), on a regular grid over a window of the state plane
//!   ([`velocity_grid`], which the LASA plots draw for the baseline too);
//! - noise-free rollouts `y_{k+1} = f(μ(f⁻¹(y_k, c)), c)` ([`Policy::mean_next`]) from
//!   given starts;
//! - the learned deformation: the image under `f(·, c)` of a regular grid of lines in
//!   the latent plane, spanning the latent box that `f⁻¹(·, c)` maps the window into.

use ciflow_engine::flow::{FlowResult, MeanDynamics, Policy};
use serde::Serialize;

use ciflow_envs::dataset::Episode;
use ciflow_envs::registry;

use crate::rollout::mean_rollout;
use crate::{EvaluationError, EvaluationResult};

/// Settings of [`field`].
#[derive(Clone, Debug, PartialEq)]
pub struct FieldConfig {
    pub contexts: Vec<Vec<f64>>,
    /// `[x_min, x_max, y_min, y_max]`; `None`: the demonstrations' bounding box (from
    /// the checkpoint) widened by a quarter of its size on every side.
    pub window: Option<[f64; 4]>,
    /// Grid points per axis.
    pub resolution: usize,
    /// Rollout starts; `None`: the window's corners and edge midpoints, 10% inside.
    pub starts: Option<Vec<[f64; 2]>>,
    pub rollout_steps: usize,
    /// Latent grid lines per axis.
    pub latent_lines: usize,
}

/// The figure data for one context.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ContextField {
    pub context: Vec<f64>,
    /// Grid abscissae and ordinates.
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    /// `velocity_x[j][i]`, `velocity_y[j][i]`: `ẏ_des` at `(x[i], y[j])`.
    pub velocity_x: Vec<Vec<f64>>,
    pub velocity_y: Vec<Vec<f64>>,
    /// One polyline per start.
    pub rollouts: Vec<Vec<[f64; 2]>>,
    /// Images of the latent grid lines (first the lines of constant `z₀`, then of `z₁`).
    pub latent_grid: Vec<Vec<[f64; 2]>>,
    /// The curve the task's motion should trace for this context, if it has one
    /// (`TaskEntry::reference_curve`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<Vec<[f64; 2]>>,
}

/// A demonstration's positions, with its first context.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DemonstrationPath {
    pub context: Vec<f64>,
    pub points: Vec<[f64; 2]>,
}

/// Outcome of [`field`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FieldReport {
    pub task: String,
    pub window: [f64; 4],
    pub fields: Vec<ContextField>,
    pub demonstrations: Vec<DemonstrationPath>,
}

const LATENT_LINE_SAMPLES: usize = 100;

pub(crate) fn linspace(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| lo + (hi - lo) * k as f64 / (n.max(2) - 1) as f64)
        .collect()
}

fn default_window(policy: &Policy) -> [f64; 4] {
    let bounds = &policy.config().bounds;
    let widen = |i: usize| {
        let (lo, hi) = (bounds.state_min[i], bounds.state_max[i]);
        let margin = 0.25 * (hi - lo).max(1e-6);
        (lo - margin, hi + margin)
    };
    let ((x0, x1), (y0, y1)) = (widen(0), widen(1));
    [x0, x1, y0, y1]
}

fn default_starts(window: &[f64; 4]) -> Vec<[f64; 2]> {
    let [x0, x1, y0, y1] = *window;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let (hx, hy) = (0.9 * (x1 - x0) / 2.0, 0.9 * (y1 - y0) / 2.0);
    [
        (-1.0, -1.0),
        (0.0, -1.0),
        (1.0, -1.0),
        (1.0, 0.0),
        (1.0, 1.0),
        (0.0, 1.0),
        (-1.0, 1.0),
        (-1.0, 0.0),
    ]
    .iter()
    .map(|(sx, sy)| [cx + sx * hx, cy + sy * hy])
    .collect()
}

/// The desired velocity `ẏ(y, c)` of a 2-D `model` on the grid `xs × ys`: its `x` and `y`
/// components, each as rows `[j][i]` at `(xs[i], ys[j])`.
pub fn velocity_grid<M: MeanDynamics>(
    model: &M,
    xs: &[f64],
    ys: &[f64],
    context: &[f64],
    ws: &mut M::Workspace,
) -> FlowResult<[Vec<Vec<f64>>; 2]> {
    let mut components = [Vec::with_capacity(ys.len()), Vec::with_capacity(ys.len())];
    let mut v = [0.0; 2];
    for &y in ys {
        let mut rows = [Vec::with_capacity(xs.len()), Vec::with_capacity(xs.len())];
        for &x in xs {
            model.velocity(&[x, y], context, ws, &mut v)?;
            rows[0].push(v[0]);
            rows[1].push(v[1]);
        }
        let [row_x, row_y] = rows;
        components[0].push(row_x);
        components[1].push(row_y);
    }
    Ok(components)
}

/// The figure data of a 2-D `policy` (module docs); `demonstrations` are copied as
/// position paths for overlays.
pub fn field(
    policy: &Policy,
    config: &FieldConfig,
    demonstrations: &[Episode],
) -> EvaluationResult<FieldReport> {
    if policy.config().state_dim != 2 {
        return Err(EvaluationError::InvalidConfig(format!(
            "vector fields need a 2-D state, the checkpoint's is {}-D",
            policy.config().state_dim
        )));
    }
    if config.resolution < 2 || config.latent_lines < 2 {
        return Err(EvaluationError::InvalidConfig(
            "the grid needs at least 2 points and 2 latent lines per axis".into(),
        ));
    }
    let window = config.window.unwrap_or_else(|| default_window(policy));
    if window.iter().any(|v| !v.is_finite()) || window[0] >= window[1] || window[2] >= window[3] {
        return Err(EvaluationError::InvalidConfig(format!(
            "the window {window:?} is empty or not finite"
        )));
    }
    let starts = config
        .starts
        .clone()
        .unwrap_or_else(|| default_starts(&window));
    let mut ws = policy.workspace();
    let xs = linspace(window[0], window[1], config.resolution);
    let ys = linspace(window[2], window[3], config.resolution);
    let reference_curve = registry::entry(&policy.config().task)?.reference_curve;
    let mut fields = Vec::with_capacity(config.contexts.len());
    for context in &config.contexts {
        let [velocity_x, velocity_y] = velocity_grid(policy, &xs, &ys, context, &mut ws)?;
        if velocity_x
            .iter()
            .chain(&velocity_y)
            .flatten()
            .any(|v| !v.is_finite())
        {
            return Err(EvaluationError::InvalidConfig(format!(
                "the field at context {context:?} is not finite: the context lies too far \
                 outside those the flow was trained on (from {:?} to {:?})",
                policy.config().bounds.context_min,
                policy.config().bounds.context_max
            )));
        }
        let (mut z_min, mut z_max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        let mut z = [0.0; 2];
        for &y in &ys {
            for &x in &xs {
                policy.latent_state(&[x, y], context, &mut ws, &mut z)?;
                for k in 0..2 {
                    z_min[k] = z_min[k].min(z[k]);
                    z_max[k] = z_max[k].max(z[k]);
                }
            }
        }
        let mut rollouts = Vec::with_capacity(starts.len());
        for start in &starts {
            let mut path = mean_rollout(policy, *start, context, config.rollout_steps, &mut ws)?;
            path.retain(|p| p.iter().all(|v| v.is_finite()));
            rollouts.push(path);
        }
        let mut latent_grid = Vec::new();
        for axis in 0..2 {
            let other = 1 - axis;
            for level in linspace(z_min[axis], z_max[axis], config.latent_lines) {
                let mut line = Vec::with_capacity(LATENT_LINE_SAMPLES);
                for s in linspace(z_min[other], z_max[other], LATENT_LINE_SAMPLES) {
                    let mut latent = [0.0; 2];
                    latent[axis] = level;
                    latent[other] = s;
                    let mut y = [0.0; 2];
                    policy.observe(&latent, context, &mut ws, &mut y)?;
                    line.push(y);
                }
                latent_grid.push(line);
            }
        }
        fields.push(ContextField {
            context: context.clone(),
            x: xs.clone(),
            y: ys.clone(),
            velocity_x,
            velocity_y,
            rollouts,
            latent_grid,
            reference: reference_curve.map(|curve| curve(context)),
        });
    }
    let demonstrations = demonstrations
        .iter()
        .filter(|e| !e.observations.is_empty() && !e.contexts.is_empty())
        .map(|e| DemonstrationPath {
            context: e.contexts[0].clone(),
            points: e.observations.iter().map(|o| [o[0], o[1]]).collect(),
        })
        .collect();
    Ok(FieldReport {
        task: policy.config().task.clone(),
        window,
        fields,
        demonstrations,
    })
}
