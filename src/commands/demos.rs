//! `ciflow demos`: record expert demonstrations of a task as a Minari dataset.

use std::path::PathBuf;

use anyhow::Context;
use ciflow_envs::dataset::{Credits, DatasetFormat};
use ciflow_envs::rollout::{Recording, record_expert_dataset};

use ciflow_cli::parse::parse_key_value;
use ciflow_cli::progress;

/// Arguments of `ciflow demos`.
#[derive(clap::Args, Debug)]
pub struct DemosArgs {
    /// Task: command-line name (limit-cycle, obstacle-avoidance, pouring, reach, lasa) or
    /// Gymnasium id.
    #[arg(long)]
    pub task: String,
    /// Number of episodes to record.
    #[arg(long, default_value_t = 100)]
    pub episodes: u64,
    /// Seed of the first episode; episode i is reset with seed + i.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Dataset directory to create (Minari layout; open it with
    /// `minari.MinariDataset("<out>/data")`).
    #[arg(long)]
    pub out: PathBuf,
    /// Construction argument of the task, NAME=VALUE (e.g. obstacles=2, shape=Sshape:
    /// a number, or a name where the task names its values); repeatable.
    #[arg(long = "kwarg", value_name = "NAME=VALUE", value_parser = parse_key_value)]
    pub kwargs: Vec<(String, String)>,
    /// Reset option for every episode, NAME=VALUE (e.g. context_set=2, demo=3,
    /// shape=4 or shape=Sshape); repeatable.
    #[arg(long = "option", value_name = "NAME=VALUE", value_parser = parse_key_value)]
    pub options: Vec<(String, String)>,
    /// Minari dataset id (default: `ciflow/<task>-expert-v0`).
    #[arg(long)]
    pub dataset_id: Option<String>,
    /// Replace an existing dataset at --out.
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub credits: Credits,
    /// The layout to write: Minari's (what `ciflow train` reads) or LeRobot v3.0.
    #[arg(long, value_enum, default_value_t)]
    pub format: DatasetFormat,
}

/// Resolves NAME=VALUE pairs to the task's numbers (names of values included).
pub fn run(args: DemosArgs) -> anyhow::Result<()> {
    let task = ciflow_envs::registry::entry(&args.task)?;
    let recording = Recording {
        task: args.task.clone(),
        kwargs: task.arguments(&args.kwargs)?,
        options: task.values(&args.options)?,
        episodes: args.episodes,
        seed: args.seed,
        dataset_id: args.dataset_id,
        credits: args.credits,
        format: args.format,
    };
    let progress = progress::bar(args.episodes, &format!("{} demos", args.task), "episodes");
    let mut steps = 0usize;
    let mut successes = 0usize;
    let spec = record_expert_dataset(&recording, &args.out, args.overwrite, |episode| {
        steps += episode.len();
        successes += usize::from(episode.succeeded());
        progress.inc(1);
    })
    .with_context(|| {
        format!(
            "recording {} demonstrations of `{}`",
            args.episodes, args.task
        )
    })?;
    progress.finish();
    println!(
        "wrote {} ({}): {} episodes, {steps} steps, {successes} successful, dt = {} s",
        args.out.display(),
        spec.dataset_id,
        args.episodes,
        spec.control_dt
    );
    Ok(())
}
