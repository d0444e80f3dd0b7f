//! `ciflow stability`: measure how often noise-free rollouts of a checkpoint converge to
//! its attractor from random starts far outside the demonstrations (observation space,
//! random contexts). Flows must print 100%; the behaviour-cloning baseline need not.

use std::path::PathBuf;

use anyhow::Context;
use ciflow_engine::flow::checkpoint;
use ciflow_engine::flow::stability::{StabilityConfig, StabilityReport, measure};
use ciflow_engine::flow::{BehaviourCloning, CheckpointConfig, Policy};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(clap::Args, Debug)]
pub struct StabilityArgs {
    /// Checkpoint directory (a flow or an MLP baseline).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Expected task name; loading a checkpoint of another task fails.
    #[arg(long)]
    pub task: Option<String>,
    /// Number of rollouts.
    #[arg(long, default_value_t = 200)]
    pub starts: usize,
    /// Starts are drawn from the demonstrations' bounding box scaled by this factor.
    #[arg(long, default_value_t = 100.0)]
    pub scale: f64,
    /// Convergence radius as a fraction of the bounding box diagonal.
    #[arg(long, default_value_t = 1e-3)]
    pub tolerance: f64,
    /// Step budget per rollout.
    #[arg(long, default_value_t = 20_000)]
    pub max_steps: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: StabilityArgs) -> anyhow::Result<()> {
    let config = StabilityConfig {
        starts: args.starts,
        scale: args.scale,
        tolerance: args.tolerance,
        max_steps: args.max_steps,
        seed: args.seed,
        ..StabilityConfig::default()
    };
    let dir = &args.checkpoint;
    let task = args.task.as_deref();
    let bar = ProgressBar::new(args.starts as u64);
    bar.set_style(
        ProgressStyle::with_template("rollouts [{bar:30}] {pos}/{len} ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let tick = |done: usize| bar.set_position(done as u64);
    let read =
        checkpoint::read_config(dir).with_context(|| format!("reading {}", dir.display()))?;
    let report: StabilityReport = match read {
        CheckpointConfig::Flow(_) => measure(&Policy::load(dir, task)?, &config, tick)?,
        CheckpointConfig::MlpBaseline(_) => {
            measure(&BehaviourCloning::load(dir, task)?, &config, tick)?
        }
    };
    bar.finish_and_clear();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "stability: {:.1}% ({}/{} rollouts from up to {}x outside the demonstrations converged \
             within {:.3e} in {} steps; {} non-finite)",
            100.0 * report.fraction,
            report.converged,
            report.rollouts,
            args.scale,
            report.tolerance,
            args.max_steps,
            report.diverged_to_non_finite,
        );
    }
    Ok(())
}
