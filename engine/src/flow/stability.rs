//! Measured global stability: noise-free rollouts *in observation space* (each step
//! inverts `f`, steps the latent state and maps it back), from random starts far outside
//! the demonstrations, for random contexts.
//!
//! Starts are drawn uniformly from the demonstrations' state bounding box scaled by
//! `scale` about its centre (`scale = 100`: up to 100× outside), contexts uniformly from
//! the context bounding box. A rollout converges when its distance to the attractor —
//! the fixed point for go-to, the orbit point of the same phase for limit cycles, the
//! demonstrations' goal for the behaviour-cloning baseline — falls below
//! `tolerance · diag(state box)` within `max_steps` steps. A non-finite state counts as
//! diverged.
//!
//! Two figures keep the verdict from hanging on one threshold: the share of rollouts that
//! end within each of [`TOLERANCE_FACTORS`] times the tolerance (a converged rollout ends
//! where it first came within the tolerance, the others after `max_steps` or where they
//! stalled); and the rollouts that *stalled* away from the attractor — their step
//! `‖y_{k+1} − y_k‖` stayed below `stall_speed · diag` for `stall_steps` consecutive
//! steps farther than the tolerance from it: end points of spurious attractors.

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::math::distance;

use super::baseline::{BaselineWorkspace, BehaviourCloning};
use super::config::Bounds;
use super::error::{FlowError, FlowResult};
use super::policy::{Policy, PolicyWorkspace};

/// A noise-free closed-form dynamics `y_{k+1} = F(y_k, c)` with a known attractor.
pub trait MeanDynamics {
    type Workspace;
    fn workspace(&self) -> Self::Workspace;
    fn bounds(&self) -> &Bounds;
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut Self::Workspace,
        out: &mut [f64],
    ) -> FlowResult<()>;
    /// Distance from `y` to the attractor; `scratch` has the state dimension.
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut Self::Workspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64>;
}

impl MeanDynamics for Policy {
    type Workspace = PolicyWorkspace;
    fn workspace(&self) -> PolicyWorkspace {
        Policy::workspace(self)
    }
    fn bounds(&self) -> &Bounds {
        &self.config().bounds
    }
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        Policy::mean_next(self, y, context, ws, out)
    }
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut PolicyWorkspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64> {
        Policy::attractor_distance(self, y, context, ws, scratch)
    }
}

impl MeanDynamics for BehaviourCloning {
    type Workspace = BaselineWorkspace;
    fn workspace(&self) -> BaselineWorkspace {
        BehaviourCloning::workspace(self)
    }
    fn bounds(&self) -> &Bounds {
        &self.config().bounds
    }
    fn mean_next(
        &self,
        y: &[f64],
        context: &[f64],
        ws: &mut BaselineWorkspace,
        out: &mut [f64],
    ) -> FlowResult<()> {
        BehaviourCloning::mean_next(self, y, context, ws, out)
    }
    fn attractor_distance(
        &self,
        y: &[f64],
        context: &[f64],
        _: &mut BaselineWorkspace,
        scratch: &mut [f64],
    ) -> FlowResult<f64> {
        self.goal(context, scratch);
        Ok(distance(y, scratch))
    }
}

/// Settings of [`measure`].
#[derive(Clone, Debug, Serialize)]
pub struct StabilityConfig {
    /// Number of rollouts (each with its own random start and context).
    pub starts: usize,
    /// Starts are drawn from the state box scaled by this factor about its centre.
    pub scale: f64,
    /// Convergence radius, as a fraction of the state box's diagonal.
    pub tolerance: f64,
    /// Step budget per rollout.
    pub max_steps: usize,
    /// The distance to the attractor is checked every this many steps.
    pub check_every: usize,
    /// A step shorter than this fraction of the state box's diagonal is stalled…
    pub stall_speed: f64,
    /// …and this many stalled steps in a row end the rollout as stalled.
    pub stall_steps: usize,
    pub seed: u64,
}

/// The multiples of the tolerance at which [`StabilityReport::within`] is reported.
pub const TOLERANCE_FACTORS: [f64; 4] = [1.0, 10.0, 100.0, 1000.0];

/// The share of rollouts ending within `factor` times the tolerance.
#[derive(Clone, Debug, Serialize)]
pub struct ShareWithin {
    pub factor: f64,
    pub fraction: f64,
}

impl Default for StabilityConfig {
    fn default() -> Self {
        Self {
            starts: 200,
            scale: 100.0,
            tolerance: 1e-3,
            max_steps: 20_000,
            check_every: 10,
            // A go-to flow at its slowest guaranteed rate (0.1 /s, 100 Hz) still moves
            // 1e-6 of the diagonal per step at the tolerance of 1e-3: ten times this.
            stall_speed: 1e-7,
            stall_steps: 200,
            seed: 0,
        }
    }
}

/// Outcome of [`measure`].
#[derive(Clone, Debug, Serialize)]
pub struct StabilityReport {
    pub rollouts: usize,
    pub converged: usize,
    /// `converged / rollouts`.
    pub fraction: f64,
    /// The convergence radius in observation units.
    pub tolerance: f64,
    /// Largest number of steps a converged rollout needed.
    pub max_steps_to_converge: usize,
    /// Largest final distance to the attractor among non-converged finite rollouts.
    pub worst_final_distance: f64,
    pub diverged_to_non_finite: usize,
    /// Rollouts that stalled farther than the tolerance from the attractor.
    pub stalled_away: usize,
    /// The share ending within each of [`TOLERANCE_FACTORS`] times the tolerance.
    pub within: Vec<ShareWithin>,
}

/// Runs the stability check; `progress` is called after each rollout.
pub fn measure<M: MeanDynamics>(
    model: &M,
    config: &StabilityConfig,
    mut progress: impl FnMut(usize),
) -> FlowResult<StabilityReport> {
    if config.starts == 0
        || config.check_every == 0
        || !(config.scale > 0.0 && config.tolerance > 0.0)
    {
        return Err(FlowError::InvalidConfig(
            "stability check needs starts, check_every >= 1 and positive scale and tolerance"
                .into(),
        ));
    }
    let bounds = model.bounds();
    let d = bounds.state_min.len();
    let tolerance = config.tolerance * bounds.state_diagonal().max(f64::MIN_POSITIVE);
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut ws = model.workspace();
    let (mut y, mut next, mut scratch) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut context = vec![0.0; bounds.context_min.len()];
    let mut report = StabilityReport {
        rollouts: config.starts,
        converged: 0,
        fraction: 0.0,
        tolerance,
        max_steps_to_converge: 0,
        worst_final_distance: 0.0,
        diverged_to_non_finite: 0,
        stalled_away: 0,
        within: Vec::new(),
    };
    let stall = config.stall_speed * bounds.state_diagonal().max(f64::MIN_POSITIVE);
    let mut final_distances = Vec::with_capacity(config.starts);
    for trial in 0..config.starts {
        sample_box(
            &bounds.state_min,
            &bounds.state_max,
            config.scale,
            &mut rng,
            &mut y,
        );
        sample_box(
            &bounds.context_min,
            &bounds.context_max,
            1.0,
            &mut rng,
            &mut context,
        );
        // A rollout that turns non-finite ends infinitely far away.
        let (mut final_distance, mut stalled) = (f64::INFINITY, 0);
        for step in 1..=config.max_steps {
            model.mean_next(&y, &context, &mut ws, &mut next)?;
            stalled = if distance(&y, &next) < stall {
                stalled + 1
            } else {
                0
            };
            std::mem::swap(&mut y, &mut next);
            if y.iter().any(|v| !v.is_finite()) {
                report.diverged_to_non_finite += 1;
                final_distance = f64::INFINITY;
                break;
            }
            let stalls = stalled >= config.stall_steps;
            if stalls || step % config.check_every == 0 || step == config.max_steps {
                final_distance = model.attractor_distance(&y, &context, &mut ws, &mut scratch)?;
                if final_distance <= tolerance {
                    report.max_steps_to_converge = report.max_steps_to_converge.max(step);
                    report.converged += 1;
                    break;
                }
                if stalls {
                    report.stalled_away += 1;
                }
                if stalls || step == config.max_steps {
                    report.worst_final_distance = report.worst_final_distance.max(final_distance);
                    break;
                }
            }
        }
        final_distances.push(final_distance);
        progress(trial + 1);
    }
    report.fraction = report.converged as f64 / report.rollouts as f64;
    report.within = TOLERANCE_FACTORS
        .iter()
        .map(|&factor| ShareWithin {
            factor,
            fraction: final_distances
                .iter()
                .filter(|&&d| d <= factor * tolerance)
                .count() as f64
                / report.rollouts as f64,
        })
        .collect();
    Ok(report)
}

/// Uniform sample from the box `[lo, hi]` scaled by `scale` about its centre.
fn sample_box(lo: &[f64], hi: &[f64], scale: f64, rng: &mut impl Rng, out: &mut [f64]) {
    for ((o, a), b) in out.iter_mut().zip(lo).zip(hi) {
        let (centre, half) = (0.5 * (a + b), 0.5 * (b - a) * scale);
        *o = centre + half * rng.random_range(-1.0..=1.0);
    }
}
