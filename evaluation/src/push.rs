//! Pushes sized to a displacement, and the recovery after them.
//!
//! A push is a world-aligned horizontal force `F u` (unit `u` drawn from the episode's
//! seed) on a link (pouring: the hand, the last link; planar tasks: the point mass) for
//! `start ≤ t < start + duration`, so the robot feels `τ_ext = J(q)ᵀ [F u; 0]`.
//!
//! **Displacement.** `δ = max_{t ≥ start} ‖p(t) − p_ref(t)‖`, where `p` is the tracked
//! point ([`Trace::point`]: pouring's spout, else the position) and `p_ref` the same
//! episode (same seed: same context and start) without the push. `F` starts at
//! [`PushConfig::initial_force`] and is rescaled until `δ* ≤ δ ≤` [`OVERSHOOT`]` δ*`
//! with `δ*` = [`PushConfig::displacement`] (`F ← F · clamp(1.25 δ*/δ, 0.1, 10)`, at most
//! [`PushConfig::max_attempts`] runs), so each episode gets about the smallest push the
//! experiment asks for, not a much larger one. `δ(F)` can jump (a push just strong enough
//! to spill ends the run early; one a little stronger may reach a joint limit), so the
//! forces tried so far bracket the threshold — the strongest that fell short of `δ*` and
//! the weakest that reached it — and a step that would leave the bracket bisects it
//! instead. If no run lands in the window, the weakest run that reached `δ*` is kept.
//!
//! **Recovery.** With `d(t) = min_s ‖p(t) − p_ref(s)‖`, the distance to the undisturbed
//! *path* (the polyline through its samples; not where it is at `t`: a pushed robot may return to the path late), the
//! recovery time is `t_r − t_end`, `t_end = start + duration`, where `t_r ≥ t_end` is the
//! first time after which `d ≤` [`PushConfig::recovery_tolerance`] until the episode ends.

use ciflow_engine::math::distance;
use ciflow_engine::sim::{Perturbation, PerturbationKind};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::summary::Summary;
use crate::trace::Trace;
use crate::{EvaluationError, EvaluationResult};

/// Largest accepted displacement, as a multiple of the required one.
pub const OVERSHOOT: f64 = 1.5;

/// Settings of a push.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PushConfig {
    /// The movable link pushed (pouring: 6, the hand; planar tasks: 0, the mass).
    pub link: usize,
    /// Start of the push, simulated s.
    pub start: f64,
    /// Duration of the push, s.
    pub duration: f64,
    /// Minimum displacement `δ*` of the tracked point, m (or the task's length unit).
    pub displacement: f64,
    /// First force magnitude tried, N.
    pub initial_force: f64,
    pub max_attempts: usize,
    /// Distance to the undisturbed path that counts as recovered.
    pub recovery_tolerance: f64,
    /// Recovery within this time after the push ends counts as prompt, s.
    pub recovery_deadline: f64,
}

impl Default for PushConfig {
    fn default() -> Self {
        Self {
            link: 0,
            start: 1.0,
            duration: 0.2,
            displacement: 0.05,
            initial_force: 10.0,
            max_attempts: 12,
            recovery_tolerance: 0.01,
            recovery_deadline: 2.0,
        }
    }
}

impl PushConfig {
    pub fn validate(&self) -> EvaluationResult<()> {
        let positive = [
            ("duration", self.duration),
            ("displacement", self.displacement),
            ("initial force", self.initial_force),
            ("recovery tolerance", self.recovery_tolerance),
            ("recovery deadline", self.recovery_deadline),
        ];
        if let Some((name, value)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            return Err(EvaluationError::InvalidConfig(format!(
                "push {name} must be finite and > 0, got {value}"
            )));
        }
        if !(self.start.is_finite() && self.start >= 0.0) || self.max_attempts == 0 {
            return Err(EvaluationError::InvalidConfig(format!(
                "push start must be finite and >= 0 (got {}) and attempts >= 1 (got {})",
                self.start, self.max_attempts
            )));
        }
        Ok(())
    }

    fn end(&self) -> f64 {
        self.start + self.duration
    }

    fn perturbation(&self, force: [f64; 3]) -> Perturbation {
        Perturbation {
            kind: PerturbationKind::LinkWrench {
                link: self.link,
                force,
                torque: [0.0; 3],
            },
            start: self.start,
            duration: self.duration,
        }
    }
}

/// What one push did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PushOutcome {
    /// The force applied, world frame, N.
    pub force: [f64; 3],
    /// `δ`: the largest distance to the undisturbed run at equal times.
    pub displacement: f64,
    /// Whether `δ ≥ δ*`.
    pub displaced: bool,
    /// Runs needed to size the force.
    pub attempts: usize,
    /// Time from the push's end to the return within tolerance of the undisturbed path,
    /// s; `None` when the episode ended outside the tolerance.
    pub recovery_time: Option<f64>,
    /// Largest distance to the undisturbed path after the push ended.
    pub max_path_distance: f64,
}

/// `δ = max_{t ≥ start} ‖p(t) − p_ref(t)‖` (module docs).
pub fn displacement(trace: &Trace, reference: &Trace, start: f64) -> f64 {
    trace
        .time
        .iter()
        .zip(&trace.point)
        .filter(|(t, _)| **t >= start - 1e-9)
        .map(|(t, p)| distance(p, reference.point_at(*t)))
        .fold(0.0, f64::max)
}

/// Distance from `p` to the segment `[a, b]`.
fn segment_distance(p: &[f64], a: &[f64], b: &[f64]) -> f64 {
    let ab2: f64 = a.iter().zip(b).map(|(x, y)| (y - x) * (y - x)).sum();
    let along: f64 = p
        .iter()
        .zip(a)
        .zip(b)
        .map(|((p, a), b)| (p - a) * (b - a))
        .sum();
    let s = if ab2 > 0.0 {
        (along / ab2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let closest: Vec<f64> = a.iter().zip(b).map(|(a, b)| a + s * (b - a)).collect();
    distance(p, &closest)
}

/// Distance from `p` to the polyline `path`.
fn path_distance(p: &[f64], path: &[Vec<f64>]) -> f64 {
    match path {
        [] => f64::INFINITY,
        [only] => distance(p, only),
        _ => path
            .windows(2)
            .map(|w| segment_distance(p, &w[0], &w[1]))
            .fold(f64::INFINITY, f64::min),
    }
}

/// The recovery time after `end` and the largest path distance after it (module docs).
pub fn recovery(trace: &Trace, reference: &Trace, end: f64, tolerance: f64) -> (Option<f64>, f64) {
    let after: Vec<(f64, f64)> = trace
        .time
        .iter()
        .zip(&trace.point)
        .filter(|(t, _)| **t >= end - 1e-9)
        .map(|(t, p)| (*t, path_distance(p, &reference.point)))
        .collect();
    let worst = after.iter().map(|(_, d)| *d).fold(0.0, f64::max);
    let last_outside = after.iter().rposition(|(_, d)| *d > tolerance);
    let recovered_at = match last_outside {
        None => after.first().map(|(t, _)| *t),
        Some(k) => after.get(k + 1).map(|(t, _)| *t),
    };
    (recovered_at.map(|t| (t - end).max(0.0)), worst)
}

/// A horizontal unit direction drawn from `seed`.
pub fn push_direction(seed: u64) -> [f64; 3] {
    let angle = ChaCha8Rng::seed_from_u64(seed).random_range(0.0..std::f64::consts::TAU);
    [angle.cos(), angle.sin(), 0.0]
}

/// Grows the force until the push displaces the tracked point by `config.displacement`
/// from `reference` (module docs); `run` runs the episode under a perturbation and
/// returns its trace with whatever else the caller needs.
pub fn sized_push<R>(
    config: &PushConfig,
    seed: u64,
    reference: &Trace,
    mut run: impl FnMut(Perturbation) -> EvaluationResult<(Trace, R)>,
) -> EvaluationResult<(R, PushOutcome)> {
    let direction = push_direction(seed);
    let mut magnitude = config.initial_force;
    // The bracket: the strongest push that fell short of δ*, the weakest that reached it.
    let mut strongest_short = 0.0_f64;
    let mut weakest_displaced: Option<Attempt<R>> = None;
    let mut attempts = 0;
    loop {
        attempts += 1;
        let force = direction.map(|u| magnitude * u);
        let (trace, result) = run(config.perturbation(force))?;
        let attempt = Attempt {
            displacement: displacement(&trace, reference, config.start),
            trace,
            result,
            force,
            magnitude,
            attempts,
        };
        let delta = attempt.displacement;
        let displaced = delta >= config.displacement;
        if displaced && delta <= OVERSHOOT * config.displacement {
            return Ok(attempt.outcome(config, reference));
        }
        let proposed = magnitude
            * if delta > 0.0 {
                (1.25 * config.displacement / delta).clamp(0.1, 10.0)
            } else {
                10.0
            };
        let weakest_so_far = displaced
            && weakest_displaced
                .as_ref()
                .is_none_or(|weakest| magnitude < weakest.magnitude);
        if attempts >= config.max_attempts {
            let kept = match weakest_displaced {
                Some(weakest) if !weakest_so_far => weakest,
                _ => attempt,
            };
            return Ok(kept.outcome(config, reference));
        }
        if weakest_so_far {
            weakest_displaced = Some(attempt);
        } else if !displaced {
            strongest_short = strongest_short.max(magnitude);
        }
        magnitude = match weakest_displaced.as_ref().map(|w| w.magnitude) {
            Some(upper) if !(strongest_short < proposed && proposed < upper) => {
                0.5 * (strongest_short + upper)
            }
            _ => proposed,
        };
    }
}

/// One pushed run while the force is being sized.
struct Attempt<R> {
    trace: Trace,
    result: R,
    force: [f64; 3],
    /// `F`, N.
    magnitude: f64,
    /// `δ` of the run.
    displacement: f64,
    /// Runs so far, this one included.
    attempts: usize,
}

impl<R> Attempt<R> {
    fn outcome(self, config: &PushConfig, reference: &Trace) -> (R, PushOutcome) {
        let (recovery_time, max_path_distance) = recovery(
            &self.trace,
            reference,
            config.end(),
            config.recovery_tolerance,
        );
        let outcome = PushOutcome {
            force: self.force,
            displacement: self.displacement,
            displaced: self.displacement >= config.displacement,
            attempts: self.attempts,
            recovery_time,
            max_path_distance,
        };
        (self.result, outcome)
    }
}

/// The push figures of an evaluation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PushSummary {
    pub required_displacement: f64,
    pub displacement: Summary,
    /// Fraction of episodes displaced by at least the required distance.
    pub displaced_fraction: f64,
    pub recovery_tolerance: f64,
    pub recovery_deadline: f64,
    /// Fraction of episodes back within tolerance of the undisturbed path by their end.
    pub recovered_fraction: f64,
    /// Fraction back within tolerance no later than the deadline after the push.
    pub recovered_within_deadline_fraction: f64,
    /// Recovery times of the episodes that recovered, s.
    pub recovery_time: Option<Summary>,
    /// Success rate among the episodes displaced by at least the required distance.
    pub success_rate_displaced: Option<f64>,
}

impl PushSummary {
    /// The summary of the pushed episodes' outcomes, each with whether the episode
    /// succeeded; `None` without any.
    pub fn of(config: &PushConfig, pushes: &[(&PushOutcome, bool)]) -> Option<Self> {
        let n = pushes.len() as f64;
        let fraction = |f: &dyn Fn(&PushOutcome) -> bool| {
            pushes.iter().filter(|(p, _)| f(p)).count() as f64 / n
        };
        let displacements: Vec<f64> = pushes.iter().map(|(p, _)| p.displacement).collect();
        let times: Vec<f64> = pushes.iter().filter_map(|(p, _)| p.recovery_time).collect();
        let displaced: Vec<bool> = pushes
            .iter()
            .filter(|(p, _)| p.displaced)
            .map(|(_, s)| *s)
            .collect();
        Some(Self {
            required_displacement: config.displacement,
            displacement: Summary::of(&displacements)?,
            displaced_fraction: fraction(&|p| p.displaced),
            recovery_tolerance: config.recovery_tolerance,
            recovery_deadline: config.recovery_deadline,
            recovered_fraction: fraction(&|p| p.recovery_time.is_some()),
            recovered_within_deadline_fraction: fraction(&|p| {
                p.recovery_time
                    .is_some_and(|t| t <= config.recovery_deadline)
            }),
            recovery_time: Summary::of(&times),
            success_rate_displaced: (!displaced.is_empty())
                .then(|| displaced.iter().filter(|s| **s).count() as f64 / displaced.len() as f64),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(points: &[[f64; 2]], dt: f64) -> Trace {
        Trace {
            time: (0..points.len()).map(|k| k as f64 * dt).collect(),
            point: points.iter().map(|p| p.to_vec()).collect(),
            ..Trace::default()
        }
    }

    #[test]
    fn displacement_compares_equal_times_after_the_start() {
        let reference = trace(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], 0.5);
        // Off by 5 before the start (ignored), 0.3 at t = 1, then back.
        let pushed = trace(&[[0.0, 5.0], [1.0, 0.0], [2.0, 0.3], [3.0, 0.0]], 0.5);
        assert!((displacement(&pushed, &reference, 1.0) - 0.3).abs() < 1e-12);
        assert!((displacement(&pushed, &reference, 0.0) - 5.0).abs() < 1e-12);
    }

    #[test]
    fn recovery_is_the_last_return_within_tolerance_of_the_path() {
        // The path is the x-axis; the pushed run leaves it, comes back, leaves, returns at t = 2.
        let reference = trace(&[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], 1.0);
        let pushed = trace(
            &[[0.0, 0.5], [0.5, 0.0], [1.5, 0.2], [2.5, 0.001], [2.9, 0.0]],
            0.5,
        );
        let (time, worst) = recovery(&pushed, &reference, 0.5, 0.01);
        assert!((time.unwrap() - 1.0).abs() < 1e-12, "{time:?}");
        assert!((worst - 0.2).abs() < 1e-12);
        // Never back: no recovery time.
        let away = trace(&[[0.0, 0.5], [1.0, 0.5]], 1.0);
        assert_eq!(recovery(&away, &reference, 0.0, 0.01).0, None);
    }

    /// A run whose push of `F` N displaces the tracked point by `plant(F)`; it returns `F`.
    fn plant_run(
        plant: impl Fn(f64) -> f64,
    ) -> impl FnMut(Perturbation) -> EvaluationResult<(Trace, f64)> {
        move |p| {
            let PerturbationKind::LinkWrench { force, .. } = p.kind else {
                unreachable!()
            };
            let magnitude = force.iter().map(|f| f * f).sum::<f64>().sqrt();
            let moved = trace(&[[0.0, 0.0], [plant(magnitude), 0.0], [0.0, 0.0]], 0.5);
            Ok((moved, magnitude))
        }
    }

    #[test]
    fn a_jump_in_the_response_keeps_the_weakest_push_that_reaches_the_displacement() {
        // 1 mm per newton up to 45 N (short of 5 cm), then a jump to 20 cm (e.g. the run
        // hits a joint limit): no force lands in [5, 7.5] cm. The bracket closes on 45 N.
        let reference = trace(&[[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]], 0.5);
        let config = PushConfig {
            start: 0.5,
            ..PushConfig::default()
        };
        let plant = |f: f64| if f < 45.0 { 0.001 * f } else { 0.2 };
        let (force, outcome) = sized_push(&config, 3, &reference, plant_run(plant)).unwrap();
        assert!(outcome.displaced);
        assert!((45.0..46.0).contains(&force), "kept {force} N");
        // Never displaced: the last run is reported as not displaced.
        let weak = |_: f64| 0.0001;
        let (_, outcome) = sized_push(&config, 3, &reference, plant_run(weak)).unwrap();
        assert!(!outcome.displaced);
    }

    #[test]
    fn the_force_grows_until_the_displacement_is_reached() {
        // A linear plant: displacement = 0.004 m per newton.
        let reference = trace(&[[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]], 0.5);
        let config = PushConfig {
            start: 0.5,
            ..PushConfig::default()
        };
        let (forces, outcome) =
            sized_push(&config, 3, &reference, plant_run(|f| 0.004 * f)).unwrap();
        assert!(outcome.displaced && outcome.attempts == 2, "{outcome:?}");
        assert!(outcome.displacement >= 0.05);
        assert!((forces * 0.004 - outcome.displacement).abs() < 1e-12);
        assert!((outcome.recovery_time.unwrap() - 0.3).abs() < 1e-12);
    }
}
