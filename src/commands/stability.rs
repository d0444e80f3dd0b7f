//! `ciflow stability`: how often noise-free rollouts of a checkpoint converge to its
//! attractor from random starts far outside the demonstrations (library:
//! [`ciflow_evaluation::stability_check`]), for random contexts from the training box and,
//! as many again, from the box scaled by `--context-scale` in its position-like
//! coordinates. Flows must print 100%; the behaviour-cloning baseline need not.
//!
//! With `--negative-control` the check also runs on the same flow with its latent run
//! backwards in time, a model of the same class whose attractor repels: the check must flag
//! at least 99% of its rollouts, or the command fails. With `--robot-loop` a flow is also
//! run through the computed-torque simulator of its robot: its task's arm with the real
//! torque and rate limits (pouring: the Panda), from starts uniform inside the joint
//! limits; for the planar tasks a point mass, from starts in the demonstrations' box
//! scaled by `--scale`. With `--engines` the observation-space rollouts run on engines
//! reachable on Zenoh ([`ciflow_bridge::spread`]).

use std::path::PathBuf;

use anyhow::Context;
use ciflow_bridge::spread;
use ciflow_envs::actor::Model;
use ciflow_envs::registry;
use ciflow_evaluation::EvaluationError;
use ciflow_evaluation::robot_loop::{RobotLoopConfig, RobotPush};
use ciflow_evaluation::stability::StabilityConfig;
use ciflow_evaluation::stability_check::{
    StabilityCheck, Stage, check_stability, check_stability_with,
};

use ciflow_cli::network::EnginesArgs;
use ciflow_cli::progress;

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
    /// check (flows only); with `--robot-loop`, driving the robot as well.
    #[arg(long)]
    pub negative_control: bool,
    /// Rollouts of the negative control (training contexts).
    #[arg(long, default_value_t = 500, requires = "negative_control")]
    pub negative_control_starts: usize,
    /// Threads for the rollouts [default: the machine's cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also drive the robot through the computed-torque layer (flows only).
    #[arg(long)]
    pub robot_loop: bool,
    /// Robot-loop rollouts, from rest at joint positions drawn uniformly over the limits.
    #[arg(long, default_value_t = 100, requires = "robot_loop")]
    pub robot_starts: usize,
    /// Robot-loop rollouts whose joint positions the JSON report keeps (for plots).
    #[arg(long, default_value_t = 0, requires = "robot_loop")]
    pub robot_traces: usize,
    /// Push every robot-loop rollout's last link with this force (N) for 0.2 s, 1 s after
    /// its start, in a random horizontal direction.
    #[arg(long, requires = "robot_loop")]
    pub robot_push: Option<f64>,
    /// Simulated seconds per robot-loop rollout.
    #[arg(long, default_value_t = 60.0, requires = "robot_loop")]
    pub robot_duration: f64,
    /// The observation-space rollouts (training and far contexts, negative control) on
    /// engines; the robot loop stays in this process.
    #[command(flatten)]
    pub on: EnginesArgs,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: StabilityArgs) -> anyhow::Result<()> {
    let dir = &args.checkpoint;
    let model = Model::load(dir, args.task.as_deref())
        .with_context(|| format!("loading the checkpoint {}", dir.display()))?;
    let rollouts = StabilityConfig {
        starts: args.starts,
        scale: args.scale,
        bounded_context: registry::entry(model.task())?.bounded_context.to_vec(),
        tolerance: args.tolerance,
        max_steps: args.max_steps,
        seed: args.seed,
        threads: match args.threads {
            Some(threads) => threads,
            None => std::thread::available_parallelism().map_or(1, usize::from),
        },
        ..StabilityConfig::default()
    };
    let robot_loop = match (&model, args.robot_loop) {
        (Model::Flow(policy), true) => Some(RobotLoopConfig {
            starts: args.robot_starts,
            duration: args.robot_duration,
            tolerance: args.tolerance * policy.config().bounds.state_diagonal(),
            seed: args.seed,
            traced: args.robot_traces,
            push: args.robot_push.map(|force| RobotPush {
                force,
                at: 1.0,
                duration: 0.2,
            }),
            ..RobotLoopConfig::default()
        }),
        (Model::Baseline(_), true) => {
            anyhow::bail!(
                "--robot-loop needs a flow checkpoint: the baseline has no desired acceleration"
            )
        }
        (_, false) => None,
    };
    let check = StabilityCheck {
        rollouts,
        far_context_scale: args.context_scale,
        negative_control_starts: args
            .negative_control
            .then_some(args.negative_control_starts),
        robot_loop,
    };
    let mut bars = progress::StageBars::new("rollouts");
    let progress = |stage: Stage, total, done| bars.update(stage, stage.name(), total, done);
    let on_engines = args
        .on
        .serve_checkpoint(dir, model.task(), &model.task_kwargs()?)?;
    let report = match on_engines {
        None => check_stability(&model, &check, progress),
        Some(on) => {
            let rollouts = |subject, config: &StabilityConfig, done: &mut dyn FnMut(usize)| {
                spread::stability_rollouts(
                    &on.client,
                    &on.engines,
                    &on.policy,
                    subject,
                    config,
                    done,
                )
                .map_err(|e| EvaluationError::Remote(Box::new(e)))
            };
            check_stability_with(&model, &check, rollouts, progress)
        }
    }
    .context("the stability check")?;
    bars.finish();
    match args.json {
        true => println!("{}", serde_json::to_string_pretty(&report)?),
        false => print!("{report}"),
    }
    Ok(report.verdict()?)
}
