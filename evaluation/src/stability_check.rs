//! The stability check of a checkpoint, as `ciflow stability` runs it: [`measure`](crate::stability::measure)d
//! rollouts in observation space for contexts from the training box and, as many again,
//! for contexts from the box scaled by `far_context_scale`; optionally the negative
//! control that the check must catch — the same flow with its latent run backwards in time
//! ([`Policy::time_reversed`]), a model of the same class whose attractor repels — and the
//! rollouts through the computed-torque simulator of the flow's robot ([`robot_loop`]),
//! with the negative control driving the robot as well when both are asked for.
//!
//! A flow must converge from every start; the behaviour-cloning baseline need not.
//! [`StabilityCheckReport::verdict`] fails when a negative control slipped through.
//!
//! [`Policy::time_reversed`]: ciflow_engine::flow::Policy::time_reversed
//! [`robot_loop`]: crate::robot_loop

use std::fmt;
use std::ops::Range;

use ciflow_engine::flow::Policy;
use ciflow_engine::robot::{JointLimits, PointMass2d, Robot};
use ciflow_engine::sim::{SimConfig, Simulator};
use ciflow_envs::actor::Model;
use ciflow_envs::registry;
use serde::{Deserialize, Serialize};

use crate::error::{EvaluationError, EvaluationResult};
use crate::robot_loop::{RobotLoopConfig, RobotLoopError, RobotLoopReport, measure_robot_loop};
use crate::stability::{self, Ending, StabilityConfig, StabilityReport};

/// The share of the negative control's rollouts the check must flag.
pub const NEGATIVE_CONTROL_FLAGGED: f64 = 0.99;

/// The robot loop's longest physics step, s.
const MAX_PHYSICS_DT: f64 = 1e-3;

/// Settings of [`check_stability`].
#[derive(Clone, Debug)]
pub struct StabilityCheck {
    /// The rollouts with contexts from the training box (their `context_scale` is 1).
    pub rollouts: StabilityConfig,
    /// The far contexts come from the training box scaled by this factor.
    pub far_context_scale: f64,
    /// Rollouts of the negative control in observation space (flows only; `None`: no
    /// control, in observation space or through the robot).
    pub negative_control_starts: Option<usize>,
    /// The robot loop (flows only; `None`: not run), for the negative control as well
    /// when it runs.
    pub robot_loop: Option<RobotLoopConfig>,
}

/// Outcome of [`check_stability`].
#[derive(Clone, Debug, Serialize)]
pub struct StabilityCheckReport {
    /// Contexts from the training box.
    pub observation_space: StabilityReport,
    /// Contexts from the box scaled by `far_context_scale`.
    pub far_contexts: StabilityReport,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub negative_control: Option<StabilityReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot_loop: Option<RobotLoopReport>,
    /// The negative control through the robot loop.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot_loop_negative_control: Option<RobotLoopReport>,
    /// What was run, for the text report.
    #[serde(skip)]
    pub check: StabilityCheck,
}

/// A stage of the check, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    TrainingContexts,
    FarContexts,
    NegativeControl,
    RobotLoop,
    RobotLoopNegativeControl,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::TrainingContexts => "training contexts",
            Stage::FarContexts => "far contexts",
            Stage::NegativeControl => "negative control",
            Stage::RobotLoop => "robot loop",
            Stage::RobotLoopNegativeControl => "robot-loop negative control",
        }
    }
}

/// Whose observation-space rollouts a stage runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Subject {
    /// The checkpoint's model.
    Model,
    /// The negative control: the flow with its latent run backwards in time.
    NegativeControl,
}

impl Subject {
    /// The endings of rollouts `trials` of `config` for this subject of `model`, in this
    /// process ([`stability::rollouts`]).
    pub fn rollouts(
        self,
        model: &Model,
        config: &StabilityConfig,
        trials: Range<usize>,
        progress: impl FnMut(usize),
    ) -> EvaluationResult<Vec<Ending>> {
        Ok(match (self, model) {
            (Subject::Model, Model::Flow(policy)) => {
                stability::rollouts(policy.as_ref(), config, trials, progress)?
            }
            (Subject::Model, Model::Baseline(baseline)) => {
                stability::rollouts(baseline.as_ref(), config, trials, progress)?
            }
            (Subject::NegativeControl, Model::Flow(policy)) => {
                stability::rollouts(&policy.time_reversed(), config, trials, progress)?
            }
            (Subject::NegativeControl, Model::Baseline(_)) => return Err(needs_a_flow()),
        })
    }

    /// The report of `config` for this subject of `model`, from all its rollouts' endings.
    pub fn report(
        self,
        model: &Model,
        config: &StabilityConfig,
        endings: &[Ending],
    ) -> EvaluationResult<StabilityReport> {
        // The reversed flow has the flow's bounds, which is all the report reads.
        Ok(match model {
            Model::Flow(policy) => StabilityReport::from_endings(policy.as_ref(), config, endings)?,
            Model::Baseline(baseline) => {
                StabilityReport::from_endings(baseline.as_ref(), config, endings)?
            }
        })
    }
}

fn needs_a_flow() -> EvaluationError {
    EvaluationError::InvalidConfig(
        "the negative control and the robot loop need a flow: the baseline has no latent to \
         reverse and no desired acceleration"
            .into(),
    )
}

/// Runs `check` on `model`; `progress(stage, total, done)` is called after each rollout.
pub fn check_stability(
    model: &Model,
    check: &StabilityCheck,
    progress: impl FnMut(Stage, usize, usize),
) -> EvaluationResult<StabilityCheckReport> {
    let in_process =
        |subject: Subject, config: &StabilityConfig, progress: &mut dyn FnMut(usize)| {
            subject.rollouts(model, config, 0..config.starts, progress)
        };
    check_stability_with(model, check, in_process, progress)
}

/// [`check_stability`] with the observation-space rollouts of each stage run by
/// `rollouts(subject, config, progress)`, which returns the endings of rollouts
/// `0..config.starts` in order (`ciflow stability --engines` runs them on engines); the
/// robot loop runs in this process.
pub fn check_stability_with(
    model: &Model,
    check: &StabilityCheck,
    mut rollouts: impl FnMut(
        Subject,
        &StabilityConfig,
        &mut dyn FnMut(usize),
    ) -> EvaluationResult<Vec<Ending>>,
    mut progress: impl FnMut(Stage, usize, usize),
) -> EvaluationResult<StabilityCheckReport> {
    let flow = model.flow();
    if flow.is_none() && (check.negative_control_starts.is_some() || check.robot_loop.is_some()) {
        return Err(needs_a_flow());
    }
    // Checked before the model's rollouts, which would otherwise run first in vain.
    if check.negative_control_starts == Some(0) {
        return Err(EvaluationError::InvalidConfig(
            "the negative control needs at least one start, got 0".into(),
        ));
    }
    let mut run = |subject: Subject, config: &StabilityConfig, stage: Stage| {
        let endings = rollouts(subject, config, &mut |done| {
            progress(stage, config.starts, done)
        })?;
        subject.report(model, config, &endings)
    };
    let observation_space = run(Subject::Model, &check.rollouts, Stage::TrainingContexts)?;
    let far = StabilityConfig {
        context_scale: check.far_context_scale,
        ..check.rollouts.clone()
    };
    let far_contexts = run(Subject::Model, &far, Stage::FarContexts)?;
    let negative_control = match check.negative_control_starts {
        Some(starts) => {
            let config = StabilityConfig {
                starts,
                ..check.rollouts.clone()
            };
            Some(run(
                Subject::NegativeControl,
                &config,
                Stage::NegativeControl,
            )?)
        }
        None => None,
    };
    let (robot_loop, robot_loop_negative_control) = match (flow, &check.robot_loop) {
        (Some(policy), Some(config)) => {
            let mut simulator = robot_simulator(policy, check.rollouts.scale)?;
            let mut measure = |policy: &Policy, stage: Stage| {
                measure_robot_loop(policy, &mut simulator, config, |done| {
                    progress(stage, config.starts, done)
                })
            };
            let report = measure(policy, Stage::RobotLoop)?;
            let control = match check.negative_control_starts {
                Some(_) => Some(measure(
                    &policy.time_reversed(),
                    Stage::RobotLoopNegativeControl,
                )?),
                None => None,
            };
            (Some(report), control)
        }
        _ => (None, None),
    };
    Ok(StabilityCheckReport {
        observation_space,
        far_contexts,
        negative_control,
        robot_loop,
        robot_loop_negative_control,
        check: check.clone(),
    })
}

/// The robot `policy` drives: its task's arm (real limits), or for the planar tasks a
/// 1 kg point mass confined to the demonstrations' box scaled by `scale` about its centre.
pub fn robot_simulator(policy: &Policy, scale: f64) -> EvaluationResult<Simulator> {
    let config = policy.config();
    // Whole physics steps of at most the tasks' 1 ms in each control period, which is the
    // policy's: a LASA shape's is its recording's sampling period (2.97 ms for Angle).
    let substeps = (config.dt / MAX_PHYSICS_DT * (1.0 - 1e-9)).ceil().max(1.0);
    let sim_config = SimConfig {
        physics_dt: config.dt / substeps,
        control_dt: config.dt,
        ..SimConfig::default()
    };
    let task = registry::entry(&config.task)?;
    let robot: Box<dyn Robot> = match task.robot {
        Some(arm) => arm(&ciflow_envs::kwargs::from_json(&config.task_kwargs)?)?,
        None => {
            let bounds = &config.bounds;
            let d = config.state_dim;
            let mut limits = JointLimits::unlimited(d);
            for i in 0..d {
                let (lo, hi) = (bounds.state_min[i], bounds.state_max[i]);
                let (centre, half) = (0.5 * (lo + hi), 0.5 * scale * (hi - lo));
                limits.q_min[i] = centre - half;
                limits.q_max[i] = centre + half;
            }
            Box::new(PointMass2d::new(1.0)?.with_limits(limits)?)
        }
    };
    if robot.dof() != config.state_dim {
        return Err(RobotLoopError::Invalid(format!(
            "task `{}` drives a {}-joint robot, the checkpoint's state is {}-D",
            task.name,
            robot.dof(),
            config.state_dim
        ))
        .into());
    }
    Ok(Simulator::new(robot, sim_config).map_err(RobotLoopError::from)?)
}

/// A negative control slipped through the check.
#[derive(Debug, thiserror::Error)]
#[error(
    "the stability check missed its negative control {place}: {converged} of {rollouts} \
     rollouts of the time-reversed flow counted as converged"
)]
pub struct NegativeControlMissed {
    /// `in observation space` or `through the robot`.
    pub place: &'static str,
    pub converged: usize,
    pub rollouts: usize,
}

impl StabilityCheckReport {
    /// Fails unless the check flagged at least [`NEGATIVE_CONTROL_FLAGGED`] of each negative
    /// control's rollouts (those that ran).
    pub fn verdict(&self) -> Result<(), NegativeControlMissed> {
        let controls = [
            (
                "in observation space",
                self.negative_control
                    .as_ref()
                    .map(|r| (r.converged, r.rollouts)),
            ),
            (
                "through the robot",
                self.robot_loop_negative_control
                    .as_ref()
                    .map(|r| (r.converged, r.rollouts)),
            ),
        ];
        for (place, control) in controls {
            if let Some((converged, rollouts)) = control
                && 1.0 - converged as f64 / (rollouts as f64) < NEGATIVE_CONTROL_FLAGGED
            {
                return Err(NegativeControlMissed {
                    place,
                    converged,
                    rollouts,
                });
            }
        }
        Ok(())
    }
}

impl fmt::Display for StabilityCheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let rollouts = &self.check.rollouts;
        let far = format!("contexts up to {}x outside", self.check.far_context_scale);
        for (report, contexts) in [
            (&self.observation_space, "training contexts"),
            (&self.far_contexts, far.as_str()),
        ] {
            writeln!(
                f,
                "stability, {contexts}: {:.1}% ({}/{} rollouts from up to {}x outside the \
                 demonstrations converged within {:.3e} in {} steps; {} non-finite, {} stalled \
                 away from the attractor)",
                100.0 * report.fraction,
                report.converged,
                report.rollouts,
                rollouts.scale,
                report.tolerance,
                rollouts.max_steps,
                report.diverged_to_non_finite,
                report.stalled_away,
            )?;
            let shares: Vec<String> = report
                .within
                .iter()
                .map(|share| format!("{:.1}% within {}x", 100.0 * share.fraction, share.factor))
                .collect();
            writeln!(f, "  ending near the attractor: {}", shares.join(", "))?;
            if let (Some(left), Some(reach)) = (report.left_start_box, report.largest_reach) {
                writeln!(
                    f,
                    "  the way there: {left} of {} paths left the {}x box their starts were \
                     drawn from (the farthest reached {reach:.1}x the demonstrations' box)",
                    report.rollouts, rollouts.scale,
                )?;
            }
        }
        if let Some(report) = &self.negative_control {
            writeln!(
                f,
                "negative control (the same flow, its latent run backwards): {:.1}% flagged \
                 ({} of {} did not converge)",
                100.0 * (1.0 - report.fraction),
                report.rollouts - report.converged,
                report.rollouts,
            )?;
        }
        if let (Some(report), Some(config)) = (&self.robot_loop, &self.check.robot_loop) {
            writeln!(
                f,
                "robot loop: {:.1}% ({}/{} computed-torque rollouts converged within {:.3e} in \
                 {} s; {} hit end stops; {} saturated the torques, in {:.2}% of {} control \
                 steps; {} steps over a speed limit; {} on the latent reference while the \
                 end-stop barrier held the robot)",
                100.0 * report.fraction,
                report.converged,
                report.rollouts,
                config.tolerance,
                config.duration,
                report.hit_end_stops,
                report.saturated,
                100.0 * report.saturated_step_fraction,
                report.steps,
                report.over_speed_steps,
                report.held_steps,
            )?;
        }
        if let Some(report) = &self.robot_loop_negative_control {
            writeln!(
                f,
                "robot-loop negative control (the same flow, its latent run backwards, \
                 driving the robot): {:.1}% flagged ({} of {} did not converge)",
                100.0 * (1.0 - report.fraction),
                report.rollouts - report.converged,
                report.rollouts,
            )?;
        }
        Ok(())
    }
}
