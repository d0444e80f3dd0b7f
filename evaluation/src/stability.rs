//! Measured global stability: noise-free rollouts *in observation space* (each step
//! inverts `f`, steps the latent state and maps it back), from random starts far outside
//! the demonstrations, for random contexts.
//!
//! Starts are drawn uniformly from the demonstrations' state bounding box scaled by
//! `scale` about its centre (`scale = 100`: up to 100× outside), cut to the joint range
//! of a policy built on a robot's limits (no state of it lies outside), contexts uniformly from
//! the context bounding box scaled by `context_scale` (angles and phases, listed in
//! `bounded_context`, stay in the box). A rollout converges when its distance to the
//! attractor — the fixed point for go-to, the orbit point of the same phase for limit
//! cycles, the demonstrations' goal for the behaviour-cloning baseline — falls below
//! `tolerance · diag(state box)` within `max_steps` steps. A non-finite state counts as
//! diverged. (No escape radius ends diverging rollouts early: stable flows pass through
//! states far beyond any such radius on their way in.)
//!
//! Two figures keep the verdict from hanging on one threshold: the share of rollouts that
//! end within each of [`TOLERANCE_FACTORS`] times the tolerance (a converged rollout ends
//! where it first came within the tolerance, the others after `max_steps` or where they
//! stalled); and the rollouts that *stalled* away from the attractor — their step
//! `‖y_{k+1} − y_k‖` stayed below `stall_speed · diag` for `stall_steps` consecutive
//! steps farther than the tolerance from it: end points of spurious attractors.
//!
//! Convergence says nothing of the way there, which a robot has to follow within its
//! limits. Each rollout also records its *reach*: the smallest scale of the state box
//! (about its centre) that holds its whole path, `max_k max_i |y_k,i − m_i| / h_i` with
//! `m` the box's centre and `h` its half-widths; a path that leaves the box its start was
//! drawn from (`reach > scale`) would run into end stops placed there.

use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use ciflow_engine::flow::{FlowError, FlowResult, MeanDynamics};

use crate::rollout::MeanStepper;

/// Settings of [`measure`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StabilityConfig {
    /// Number of rollouts (each with its own random start and context).
    pub starts: usize,
    /// Starts are drawn from the state box scaled by this factor about its centre.
    pub scale: f64,
    /// Contexts are drawn from the context box scaled by this factor about its centre
    /// (1: the training contexts' box)…
    pub context_scale: f64,
    /// …except these coordinates, which keep to the box: angles and phases, whose
    /// physical range the box already spans.
    pub bounded_context: Vec<usize>,
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
    /// Rollouts run on this many threads (the report does not depend on it).
    pub threads: usize,
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
            context_scale: 1.0,
            bounded_context: Vec::new(),
            tolerance: 1e-3,
            max_steps: 20_000,
            check_every: 10,
            // A go-to flow at its slowest guaranteed rate (0.1 /s, 100 Hz) still moves
            // 1e-6 of the diagonal per step at the tolerance of 1e-3: ten times this.
            stall_speed: 1e-7,
            stall_steps: 200,
            seed: 0,
            threads: 1,
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
    /// The context box's scale the contexts were drawn from (1: the training box).
    pub context_scale: f64,
    /// Largest number of steps a converged rollout needed.
    pub max_steps_to_converge: usize,
    /// Largest final distance to the attractor among non-converged finite rollouts.
    pub worst_final_distance: f64,
    pub diverged_to_non_finite: usize,
    /// Rollouts that stalled farther than the tolerance from the attractor.
    pub stalled_away: usize,
    /// The share ending within each of [`TOLERANCE_FACTORS`] times the tolerance.
    pub within: Vec<ShareWithin>,
    /// Rollouts whose path left the box the starts were drawn from (reach > `scale`),
    /// diverged ones included; `None` when an ending came without its reach (from an
    /// engine of an earlier build).
    pub left_start_box: Option<usize>,
    /// The largest reach of a finite rollout's path, in state boxes (module docs); `None`
    /// as above.
    pub largest_reach: Option<f64>,
}

/// How one rollout ended: what [`rollouts`] returns per rollout and
/// [`StabilityReport::from_endings`] counts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "ending", rename_all = "snake_case")]
pub enum Ending {
    Converged {
        steps: usize,
        /// Optional on the wire: engines of earlier builds do not send it.
        #[serde(default)]
        reach: Option<f64>,
    },
    NonFinite,
    Stalled {
        distance: f64,
        #[serde(default)]
        reach: Option<f64>,
    },
    OutOfSteps {
        distance: f64,
        #[serde(default)]
        reach: Option<f64>,
    },
}

impl Ending {
    /// The rollout's reach (module docs; infinite when it left for a non-finite state),
    /// if measured.
    pub fn reach(self) -> Option<f64> {
        match self {
            Ending::NonFinite => Some(f64::INFINITY),
            Ending::Converged { reach, .. }
            | Ending::Stalled { reach, .. }
            | Ending::OutOfSteps { reach, .. } => reach,
        }
    }

    /// Distance to the attractor where the rollout ended (infinite when it left).
    fn distance(self, tolerance: f64) -> f64 {
        match self {
            Ending::Converged { .. } => tolerance,
            Ending::NonFinite => f64::INFINITY,
            Ending::Stalled { distance, .. } | Ending::OutOfSteps { distance, .. } => distance,
        }
    }
}

/// Runs the stability check; `progress` is called with the number of finished rollouts.
/// Rollout `i` draws its start and context from its own stream of the seed, so the report
/// is the same for any number of threads.
pub fn measure<M: MeanDynamics + Sync>(
    model: &M,
    config: &StabilityConfig,
    progress: impl FnMut(usize),
) -> FlowResult<StabilityReport> {
    let endings = rollouts(model, config, 0..config.starts, progress)?;
    StabilityReport::from_endings(model, config, &endings)
}

/// Refuses settings no rollout can run with.
fn validate<M: MeanDynamics>(model: &M, config: &StabilityConfig) -> FlowResult<()> {
    let context_dim = model.bounds().context_min.len();
    // Named one by one: the flags that set them differ from command to command.
    let counts = [
        ("starts", config.starts),
        ("rollout steps", config.max_steps),
        ("steps between convergence checks", config.check_every),
        ("threads", config.threads),
    ];
    if let Some((name, _)) = counts.iter().find(|(_, count)| *count == 0) {
        return Err(FlowError::InvalidConfig(format!(
            "the stability check needs at least one of its {name}, got 0"
        )));
    }
    let positive = [
        ("start scale", config.scale),
        ("context scale", config.context_scale),
        ("tolerance", config.tolerance),
    ];
    if let Some((name, value)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return Err(FlowError::InvalidConfig(format!(
            "the stability check's {name} must be finite and > 0, got {value}"
        )));
    }
    if let Some(i) = config.bounded_context.iter().find(|&&i| i >= context_dim) {
        return Err(FlowError::InvalidConfig(format!(
            "bounded context coordinate {i} of a {context_dim}-D context"
        )));
    }
    Ok(())
}

/// The endings of rollouts `trials` (indices below `config.starts`) of the check
/// `config`, in order, on `config.threads` threads; `progress` is called with the number
/// finished. Rollout `i` depends only on `i` and the seed, so rollouts run apart (other
/// threads, processes, machines) add up to one run's.
pub fn rollouts<M: MeanDynamics + Sync>(
    model: &M,
    config: &StabilityConfig,
    trials: Range<usize>,
    mut progress: impl FnMut(usize),
) -> FlowResult<Vec<Ending>> {
    validate(model, config)?;
    if trials.end > config.starts {
        return Err(FlowError::InvalidConfig(format!(
            "rollouts {}..{} of a check of {}",
            trials.start, trials.end, config.starts
        )));
    }
    let diagonal = model.bounds().state_diagonal().max(f64::MIN_POSITIVE);
    let tolerance = config.tolerance * diagonal;
    let count = trials.len();
    let next_trial = AtomicUsize::new(trials.start);
    let finished = AtomicUsize::new(0);
    let mut endings = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..config.threads.min(count))
            .map(|_| {
                scope.spawn(|| {
                    let mut endings = Vec::new();
                    let mut rollout = Rollout::new(model, config, tolerance, diagonal);
                    loop {
                        let trial = next_trial.fetch_add(1, Ordering::Relaxed);
                        if trial >= trials.end {
                            return FlowResult::Ok(endings);
                        }
                        endings.push((trial, rollout.run(trial)?));
                        finished.fetch_add(1, Ordering::Relaxed);
                    }
                })
            })
            .collect();
        let mut reported = 0;
        while workers.iter().any(|w| !w.is_finished()) {
            let done = finished.load(Ordering::Relaxed);
            if done != reported {
                progress(done);
                reported = done;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let mut endings = Vec::with_capacity(count);
        for worker in workers {
            // A worker's panic is a bug: it goes on unwinding here, message intact.
            let worker = worker
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            endings.extend(worker?);
        }
        progress(count);
        FlowResult::Ok(endings)
    })?;
    endings.sort_by_key(|(trial, _)| *trial);
    Ok(endings.into_iter().map(|(_, ending)| ending).collect())
}

impl StabilityReport {
    /// The report of the check `config` of `model` from the endings of all its rollouts.
    pub fn from_endings<M: MeanDynamics>(
        model: &M,
        config: &StabilityConfig,
        endings: &[Ending],
    ) -> FlowResult<Self> {
        validate(model, config)?;
        if endings.len() != config.starts {
            return Err(FlowError::InvalidConfig(format!(
                "{} rollout endings for a check of {}",
                endings.len(),
                config.starts
            )));
        }
        let diagonal = model.bounds().state_diagonal().max(f64::MIN_POSITIVE);
        let tolerance = config.tolerance * diagonal;
        let mut report = StabilityReport {
            rollouts: config.starts,
            converged: 0,
            fraction: 0.0,
            tolerance,
            context_scale: config.context_scale,
            max_steps_to_converge: 0,
            worst_final_distance: 0.0,
            diverged_to_non_finite: 0,
            stalled_away: 0,
            within: Vec::new(),
            left_start_box: None,
            largest_reach: None,
        };
        if let Some(reaches) = endings
            .iter()
            .map(|e| e.reach())
            .collect::<Option<Vec<_>>>()
        {
            report.left_start_box = Some(reaches.iter().filter(|&&r| r > config.scale).count());
            let finite = reaches.iter().filter(|r| r.is_finite());
            report.largest_reach = Some(finite.fold(0.0, |a, &r| f64::max(a, r)));
        }
        for ending in endings {
            match *ending {
                Ending::Converged { steps, .. } => {
                    report.converged += 1;
                    report.max_steps_to_converge = report.max_steps_to_converge.max(steps);
                }
                Ending::NonFinite => report.diverged_to_non_finite += 1,
                Ending::Stalled { distance, .. } | Ending::OutOfSteps { distance, .. } => {
                    report.stalled_away += usize::from(matches!(ending, Ending::Stalled { .. }));
                    report.worst_final_distance = report.worst_final_distance.max(distance);
                }
            }
        }
        report.fraction = report.converged as f64 / report.rollouts as f64;
        report.within = TOLERANCE_FACTORS
            .iter()
            .map(|&factor| ShareWithin {
                factor,
                fraction: endings
                    .iter()
                    .filter(|e| e.distance(tolerance) <= factor * tolerance)
                    .count() as f64
                    / report.rollouts as f64,
            })
            .collect();
        Ok(report)
    }
}

/// One worker's model workspace and buffers.
struct Rollout<'a, M: MeanDynamics> {
    model: &'a M,
    config: &'a StabilityConfig,
    ws: M::Workspace,
    stepper: MeanStepper<'a, M>,
    scratch: Vec<f64>,
    context: Vec<f64>,
    /// Radii in observation units: converged and stalled step.
    tolerance: f64,
    stall: f64,
    /// The state box's centre and half-widths, which a reach is measured in.
    centre: Vec<f64>,
    half: Vec<f64>,
}

impl<'a, M: MeanDynamics> Rollout<'a, M> {
    fn new(model: &'a M, config: &'a StabilityConfig, tolerance: f64, diagonal: f64) -> Self {
        let bounds = model.bounds();
        let d = bounds.state_min.len();
        Self {
            model,
            config,
            ws: model.workspace(),
            stepper: MeanStepper::new(model),
            scratch: vec![0.0; d],
            context: vec![0.0; bounds.context_min.len()],
            tolerance,
            stall: config.stall_speed * diagonal,
            centre: (bounds.state_min.iter().zip(&bounds.state_max))
                .map(|(lo, hi)| 0.5 * (lo + hi))
                .collect(),
            // A flat side of the box (one value in the data) measures in units of the
            // diagonal instead of dividing by zero.
            half: (bounds.state_min.iter().zip(&bounds.state_max))
                .map(|(lo, hi)| {
                    (0.5 * (hi - lo))
                        .max(1e-9 * diagonal)
                        .max(f64::MIN_POSITIVE)
                })
                .collect(),
        }
    }

    /// The smallest scale of the state box that holds `y` (module docs).
    fn reach_of(&self, y: &[f64]) -> f64 {
        y.iter()
            .zip(self.centre.iter().zip(&self.half))
            .map(|(y, (m, h))| (y - m).abs() / h)
            .fold(0.0, f64::max)
    }

    /// Rollout `trial`: its start and context, then steps until it ends.
    fn run(&mut self, trial: usize) -> FlowResult<Ending> {
        let (config, bounds) = (self.config, self.model.bounds());
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        rng.set_stream(trial as u64);
        sample_box(
            &bounds.state_min,
            &bounds.state_max,
            config.scale,
            self.model.state_range(),
            &mut rng,
            self.stepper.state_mut(),
        );
        sample_box(
            &bounds.context_min,
            &bounds.context_max,
            config.context_scale,
            None,
            &mut rng,
            &mut self.context,
        );
        for &i in &config.bounded_context {
            self.context[i] = rng.random_range(bounds.context_min[i]..=bounds.context_max[i]);
        }
        let (mut step, mut stalled) = (0, 0);
        let mut reach = self.reach_of(self.stepper.state());
        loop {
            step += 1;
            stalled = match self.stepper.step(&self.context, &mut self.ws)? < self.stall {
                true => stalled + 1,
                false => 0,
            };
            let y = self.stepper.state();
            if y.iter().any(|v| !v.is_finite()) {
                return Ok(Ending::NonFinite);
            }
            reach = reach.max(self.reach_of(y));
            let (stalls, last) = (stalled >= config.stall_steps, step >= config.max_steps);
            if stalls || last || step % config.check_every == 0 {
                let distance = self.model.attractor_distance(
                    y,
                    &self.context,
                    &mut self.ws,
                    &mut self.scratch,
                )?;
                let reach = Some(reach);
                if distance <= self.tolerance {
                    return Ok(Ending::Converged { steps: step, reach });
                }
                if stalls {
                    return Ok(Ending::Stalled { distance, reach });
                }
                if last {
                    return Ok(Ending::OutOfSteps { distance, reach });
                }
            }
        }
    }
}

/// Uniform sample from the box `[lo, hi]` scaled by `scale` about its centre, cut to
/// `range` when given.
fn sample_box(
    lo: &[f64],
    hi: &[f64],
    scale: f64,
    range: Option<(&[f64], &[f64])>,
    rng: &mut impl Rng,
    out: &mut [f64],
) {
    for (i, o) in out.iter_mut().enumerate() {
        let (centre, half) = (0.5 * (lo[i] + hi[i]), 0.5 * (hi[i] - lo[i]) * scale);
        let (mut from, mut to) = (centre - half, centre + half);
        if let Some((min, max)) = range {
            from = from.max(min[i]);
            to = to.min(max[i]).max(from);
        }
        *o = rng.random_range(from..=to);
    }
}
