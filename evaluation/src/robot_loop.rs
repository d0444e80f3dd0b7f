//! Measured closed-loop stability through the computed-torque simulator: the policy's
//! desired acceleration ([`Policy::acceleration_held`], one end-stop hold per rollout)
//! drives [`Simulator::step`] from random joint configurations drawn uniformly inside the
//! robot's position limits (at rest), for random contexts. This is where torque and rate
//! saturation and the end stops — which the module-level claims exclude — are measured
//! rather than assumed.
//!
//! A rollout converges when, within `duration`, the joint state reaches the attractor:
//! `‖q - q*‖ ≤ tolerance` and `‖q̇‖ ≤ tolerance`/s for go-to policies, distance to the
//! orbit `≤ tolerance` for limit cycles. A rollout ends when it converges, so the share of
//! saturated control steps is over the steps it took to get there.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use ciflow_engine::flow::{EndStopHold, FlowError, Policy};
use ciflow_engine::sim::{Perturbation, PerturbationKind, SimError, Simulator};

#[derive(Debug, thiserror::Error)]
pub enum RobotLoopError {
    #[error(transparent)]
    Flow(#[from] FlowError),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error("robot-loop check: {0}")]
    Invalid(String),
}

/// Settings of [`measure_robot_loop`].
#[derive(Clone, Debug, Serialize)]
pub struct RobotLoopConfig {
    pub starts: usize,
    /// `K_v` of the acceleration policy (1/s).
    pub velocity_gain: f64,
    /// Simulated time per rollout, s.
    pub duration: f64,
    /// Joint-space convergence radius (rad or m).
    pub tolerance: f64,
    /// Convergence is checked every this many control periods.
    pub check_every: usize,
    pub seed: u64,
    /// The first this many rollouts' joint positions are kept in the report (sampled every
    /// `check_every` periods), for plots against the limits.
    pub traced: usize,
    /// A push on the last link of every rollout, in a random horizontal direction.
    pub push: Option<RobotPush>,
}

/// A horizontal force on the robot's last link.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct RobotPush {
    /// N.
    pub force: f64,
    /// Start, simulated s after the rollout's start.
    pub at: f64,
    /// s.
    pub duration: f64,
}

impl Default for RobotLoopConfig {
    fn default() -> Self {
        Self {
            starts: 20,
            velocity_gain: 10.0,
            duration: 20.0,
            tolerance: 1e-3,
            check_every: 10,
            seed: 0,
            traced: 0,
            push: None,
        }
    }
}

/// Outcome of [`measure_robot_loop`].
#[derive(Clone, Debug, Serialize)]
pub struct RobotLoopReport {
    pub rollouts: usize,
    pub converged: usize,
    pub fraction: f64,
    /// Rollouts in which the torque or rate limits changed the computed torque at least once.
    pub saturated: usize,
    /// Rollouts in which a joint hit an end stop.
    pub hit_end_stops: usize,
    /// Control periods simulated, over all rollouts (each until it converged).
    pub steps: usize,
    /// Control periods in which the torque or rate limits changed the computed torque.
    pub saturated_steps: usize,
    /// `saturated_steps / steps`.
    pub saturated_step_fraction: f64,
    /// Control periods that ended with a joint faster than its speed limit.
    pub over_speed_steps: usize,
    /// Control periods in which the policy followed its own latent state while the
    /// end-stop barrier held the robot back ([`EndStopHold`]).
    pub held_steps: usize,
    /// The push every rollout took, if any.
    pub push: Option<RobotPush>,
    /// The robot's position limits and the traced rollouts ([`RobotLoopConfig::traced`]).
    pub position_min: Vec<f64>,
    pub position_max: Vec<f64>,
    pub traces: Vec<JointTrace>,
}

/// One rollout's joint positions, `positions[k]` at `k · period` seconds.
#[derive(Clone, Debug, Serialize)]
pub struct JointTrace {
    pub period: f64,
    pub positions: Vec<Vec<f64>>,
}

/// Runs the closed-loop check on `simulator` (whose robot has `policy`'s state dimension
/// and finite position limits); `progress` is called after each rollout.
pub fn measure_robot_loop(
    policy: &Policy,
    simulator: &mut Simulator,
    config: &RobotLoopConfig,
    mut progress: impl FnMut(usize),
) -> Result<RobotLoopReport, RobotLoopError> {
    let d = policy.config().state_dim;
    let limits = simulator.robot().limits().clone();
    if limits.q_min.len() != d {
        return Err(RobotLoopError::Invalid(format!(
            "robot has {} joints, the policy {d} states",
            limits.q_min.len()
        )));
    }
    if limits
        .q_min
        .iter()
        .chain(limits.q_max.iter())
        .any(|v| !v.is_finite())
    {
        return Err(RobotLoopError::Invalid(
            "starts need finite position limits".into(),
        ));
    }
    if config.starts == 0
        || config.check_every == 0
        || !(config.duration > 0.0 && config.tolerance > 0.0)
    {
        return Err(RobotLoopError::Invalid(
            "starts, check_every, duration and tolerance must be positive".into(),
        ));
    }
    let periods = (config.duration / simulator.config().control_dt).ceil() as usize;
    let bounds = &policy.config().bounds;
    let go_to = policy.latent().kind().is_go_to();
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut ws = policy.workspace();
    let mut hold = EndStopHold::new(d, simulator.config().control_dt)?;
    let (mut acceleration, mut velocity, mut scratch) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut context = vec![0.0; bounds.context_min.len()];
    let mut report = RobotLoopReport {
        rollouts: config.starts,
        converged: 0,
        fraction: 0.0,
        saturated: 0,
        hit_end_stops: 0,
        steps: 0,
        saturated_steps: 0,
        saturated_step_fraction: 0.0,
        over_speed_steps: 0,
        held_steps: 0,
        push: config.push,
        position_min: limits.q_min.as_slice().to_vec(),
        position_max: limits.q_max.as_slice().to_vec(),
        traces: Vec::new(),
    };
    let trace_period = config.check_every as f64 * simulator.config().control_dt;
    for trial in 0..config.starts {
        let q0: Vec<f64> = (0..d)
            .map(|i| rng.random_range(limits.q_min[i]..=limits.q_max[i]))
            .collect();
        for (c, (lo, hi)) in context
            .iter_mut()
            .zip(bounds.context_min.iter().zip(&bounds.context_max))
        {
            *c = rng.random_range(*lo..=*hi);
        }
        simulator.reset(&q0, &vec![0.0; d])?;
        hold.clear();
        if let Some(push) = config.push {
            let heading = rng.random_range(0.0..std::f64::consts::TAU);
            simulator.perturb(Perturbation {
                kind: PerturbationKind::LinkWrench {
                    link: simulator.robot().link_count() - 1,
                    force: [push.force * heading.cos(), push.force * heading.sin(), 0.0],
                    torque: [0.0; 3],
                },
                start: push.at,
                duration: push.duration,
            })?;
        }
        let (mut saturated, mut end_stop) = (false, false);
        let mut trace = (trial < config.traced).then(|| JointTrace {
            period: trace_period,
            positions: vec![q0.clone()],
        });
        for period in 1..=periods {
            let (q, qd) = (simulator.q().as_slice(), simulator.qd().as_slice());
            policy.acceleration_held(
                q,
                qd,
                &context,
                config.velocity_gain,
                &mut hold,
                &mut ws,
                &mut acceleration,
                &mut velocity,
            )?;
            let step = simulator.step(&acceleration)?;
            report.steps += 1;
            report.held_steps += usize::from(hold.is_engaged());
            report.saturated_steps += usize::from(step.saturation.is_active());
            report.over_speed_steps += usize::from(!step.over_speed.is_empty());
            saturated |= step.saturation.is_active();
            end_stop |= !step.end_stops.is_empty();
            if period % config.check_every == 0 {
                let (q, qd) = (simulator.q().as_slice(), simulator.qd().as_slice());
                if let Some(trace) = trace.as_mut() {
                    trace.positions.push(q.to_vec());
                }
                let distance = policy.attractor_distance(q, &context, &mut ws, &mut scratch)?;
                let speed = qd.iter().map(|v| v * v).sum::<f64>().sqrt();
                if distance <= config.tolerance && (!go_to || speed <= config.tolerance) {
                    report.converged += 1;
                    break;
                }
            }
        }
        report.saturated += usize::from(saturated);
        report.hit_end_stops += usize::from(end_stop);
        report.traces.extend(trace);
        progress(trial + 1);
    }
    report.fraction = report.converged as f64 / report.rollouts as f64;
    report.saturated_step_fraction = report.saturated_steps as f64 / report.steps.max(1) as f64;
    Ok(report)
}
