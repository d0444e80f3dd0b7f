//! `ciflow stability`: measure how often noise-free rollouts of a checkpoint converge to
//! its attractor from random starts far outside the demonstrations (observation space),
//! for random contexts from the training box and, as many again, from the box scaled by
//! `--context-scale` in its position-like coordinates. Flows must print 100%; the
//! behaviour-cloning baseline need not.
//!
//! With `--negative-control` the check also runs on the same flow with its latent run
//! backwards in time (`Policy::time_reversed`), a model of the same class whose attractor
//! repels: the check must flag at least 99% of its rollouts, or the command fails.
//!
//! With `--robot-loop` a flow is also run through the computed-torque simulator of its
//! robot (`ciflow_evaluation::robot_loop`): its task's arm with the real torque and rate limits
//! (pouring: the Panda), from starts uniform inside the joint limits; for the planar
//! tasks a point mass, from starts in the demonstrations' box scaled by `--scale`.

use std::path::PathBuf;

use anyhow::Context;
use ciflow_engine::flow::{MeanDynamics, Policy};
use ciflow_engine::robot::{JointLimits, PointMass2d, Robot};
use ciflow_engine::sim::{SimConfig, Simulator};
use ciflow_envs::actor::Model;
use ciflow_envs::registry;
use ciflow_evaluation::robot_loop::{RobotLoopConfig, RobotLoopReport, measure_robot_loop};
use ciflow_evaluation::stability::{StabilityConfig, StabilityReport, measure};
use serde::Serialize;

use crate::progress;

#[derive(clap::Args, Debug)]
pub struct StabilityArgs {
    /// Checkpoint directory (a flow or an MLP baseline).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Expected task name; loading a checkpoint of another task fails.
    #[arg(long)]
    pub task: Option<String>,
    /// Rollouts per context regime: with contexts from the training box, and as many with
    /// contexts from the box scaled by --context-scale.
    #[arg(long, default_value_t = 5_000)]
    pub starts: usize,
    /// Starts are drawn from the demonstrations' bounding box scaled by this factor.
    #[arg(long, default_value_t = 100.0)]
    pub scale: f64,
    /// The far contexts come from the training contexts' box scaled by this factor about
    /// its centre, in the position-like coordinates (angles and phases stay in the box).
    #[arg(long, default_value_t = 10.0)]
    pub context_scale: f64,
    /// Convergence radius as a fraction of the bounding box diagonal.
    #[arg(long, default_value_t = 1e-3)]
    pub tolerance: f64,
    /// Step budget per rollout.
    #[arg(long, default_value_t = 20_000)]
    pub max_steps: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Also check the flow with its latent run backwards in time, which must fail the
    /// check (flows only).
    #[arg(long)]
    pub negative_control: bool,
    /// Rollouts of the negative control (training contexts).
    #[arg(long, default_value_t = 500)]
    pub negative_control_starts: usize,
    /// Threads for the rollouts [default: the machine's cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also drive the robot through the computed-torque layer (flows only).
    #[arg(long)]
    pub robot_loop: bool,
    /// Robot-loop rollouts.
    #[arg(long, default_value_t = 20)]
    pub robot_starts: usize,
    /// Simulated seconds per robot-loop rollout.
    #[arg(long, default_value_t = 60.0)]
    pub robot_duration: f64,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Everything `--json` prints.
#[derive(Serialize)]
struct Report {
    /// Contexts from the training box.
    observation_space: StabilityReport,
    /// Contexts from the box scaled by `--context-scale`.
    far_contexts: StabilityReport,
    #[serde(skip_serializing_if = "Option::is_none")]
    negative_control: Option<StabilityReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    robot_loop: Option<RobotLoopReport>,
}

/// [`measure`] behind a progress bar labelled `what`.
fn measured<M: MeanDynamics + Sync>(
    model: &M,
    config: &StabilityConfig,
    what: &str,
) -> anyhow::Result<StabilityReport> {
    let bar = progress::bar(config.starts as u64, what, "rollouts");
    let report = measure(model, config, |done| bar.set_position(done as u64));
    bar.finish_and_clear();
    report.with_context(|| format!("the stability check ({what})"))
}

/// The robot `policy` drives: its task's arm (real limits), or for the planar tasks a
/// 1 kg point mass confined to the demonstrations' box scaled by `scale` about its centre.
fn robot_simulator(policy: &Policy, scale: f64) -> anyhow::Result<Simulator> {
    let config = policy.config();
    let sim_config = SimConfig {
        physics_dt: config.dt.min(1e-3),
        control_dt: config.dt,
        ..SimConfig::default()
    };
    let task = registry::entry(&config.task)?;
    let robot: Box<dyn Robot> = match task.robot {
        Some(arm) => arm(),
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
    anyhow::ensure!(
        robot.dof() == config.state_dim,
        "task `{}` drives a {}-joint robot, the checkpoint's state is {}-D",
        task.name,
        robot.dof(),
        config.state_dim
    );
    Ok(Simulator::new(robot, sim_config)?)
}

pub fn run(args: StabilityArgs) -> anyhow::Result<()> {
    let dir = &args.checkpoint;
    let model = Model::load(dir, args.task.as_deref())
        .with_context(|| format!("loading the checkpoint {}", dir.display()))?;
    if let (Model::Baseline(_), true) = (&model, args.negative_control || args.robot_loop) {
        anyhow::bail!(
            "--negative-control and --robot-loop need a flow checkpoint: the baseline has no \
             latent to reverse and no desired acceleration"
        );
    }
    let threads = match args.threads {
        Some(threads) => threads,
        None => std::thread::available_parallelism().map_or(1, usize::from),
    };
    let config = StabilityConfig {
        starts: args.starts,
        scale: args.scale,
        bounded_context: registry::entry(model.task())?.bounded_context.to_vec(),
        tolerance: args.tolerance,
        max_steps: args.max_steps,
        seed: args.seed,
        threads,
        ..StabilityConfig::default()
    };
    let far = StabilityConfig {
        context_scale: args.context_scale,
        ..config.clone()
    };
    let check = |config: &StabilityConfig, what: &str| match &model {
        Model::Flow(policy) => measured(policy.as_ref(), config, what),
        Model::Baseline(baseline) => measured(baseline.as_ref(), config, what),
    };
    let observation_space = check(&config, "training contexts")?;
    let far_contexts = check(&far, "far contexts")?;
    let negative_control = match (&model, args.negative_control) {
        (Model::Flow(policy), true) => {
            let config = StabilityConfig {
                starts: args.negative_control_starts,
                ..config.clone()
            };
            Some(measured(
                &policy.time_reversed(),
                &config,
                "negative control",
            )?)
        }
        _ => None,
    };
    let robot_loop = match (&model, args.robot_loop) {
        (Model::Flow(policy), true) => {
            let loop_config = RobotLoopConfig {
                starts: args.robot_starts,
                duration: args.robot_duration,
                tolerance: args.tolerance * policy.config().bounds.state_diagonal(),
                seed: args.seed,
                ..RobotLoopConfig::default()
            };
            let mut simulator = robot_simulator(policy, args.scale)?;
            let bar = progress::bar(args.robot_starts as u64, "robot loop", "rollouts");
            let report = measure_robot_loop(policy, &mut simulator, &loop_config, |done| {
                bar.set_position(done as u64)
            })?;
            bar.finish_and_clear();
            Some((report, loop_config))
        }
        _ => None,
    };
    if args.json {
        let report = Report {
            observation_space,
            far_contexts,
            negative_control: negative_control.clone(),
            robot_loop: robot_loop.map(|(report, _)| report),
        };
        println!("{}", serde_json::to_string_pretty(&report)?);
        return check_negative_control(negative_control.as_ref());
    }
    for (report, contexts) in [
        (&observation_space, "training contexts".to_string()),
        (
            &far_contexts,
            format!("contexts up to {}x outside", args.context_scale),
        ),
    ] {
        println!(
            "stability, {contexts}: {:.1}% ({}/{} rollouts from up to {}x outside the \
             demonstrations converged within {:.3e} in {} steps; {} non-finite, {} stalled away \
             from the attractor)",
            100.0 * report.fraction,
            report.converged,
            report.rollouts,
            args.scale,
            report.tolerance,
            args.max_steps,
            report.diverged_to_non_finite,
            report.stalled_away,
        );
        let shares: Vec<String> = report
            .within
            .iter()
            .map(|share| format!("{:.1}% within {}x", 100.0 * share.fraction, share.factor))
            .collect();
        println!("  ending near the attractor: {}", shares.join(", "));
    }
    if let Some(report) = &negative_control {
        println!(
            "negative control (the same flow, its latent run backwards): {:.1}% flagged \
             ({} of {} did not converge)",
            100.0 * (1.0 - report.fraction),
            report.rollouts - report.converged,
            report.rollouts,
        );
    }
    if let Some((report, config)) = robot_loop {
        println!(
            "robot loop: {:.1}% ({}/{} computed-torque rollouts converged within {:.3e} in {} s; \
             {} saturated the torques, {} hit end stops)",
            100.0 * report.fraction,
            report.converged,
            report.rollouts,
            config.tolerance,
            config.duration,
            report.saturated,
            report.hit_end_stops,
        );
    }
    check_negative_control(negative_control.as_ref())
}

/// The share of the negative control's rollouts the check must flag.
const NEGATIVE_CONTROL_FLAGGED: f64 = 0.99;

/// Fails unless the check flagged the negative control's rollouts.
fn check_negative_control(report: Option<&StabilityReport>) -> anyhow::Result<()> {
    match report {
        Some(report) if 1.0 - report.fraction < NEGATIVE_CONTROL_FLAGGED => anyhow::bail!(
            "the stability check missed its negative control: {} of {} rollouts of the \
             time-reversed flow counted as converged",
            report.converged,
            report.rollouts
        ),
        _ => Ok(()),
    }
}
