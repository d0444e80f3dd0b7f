//! `ciflow evaluate`: measure a checkpoint for the experiments' report (library:
//! [`ciflow_evaluation`]). Three modes, each writing JSON:
//!
//! - default: closed-loop episodes in the task's environment from random contexts and
//!   starts, optionally pushed (`--perturb push`) or with the context moved mid-motion
//!   (`--perturb context`): rates, distances, push displacement and recovery, traces —
//!   of the checkpoint, or with `--expert --task T` of the task's expert, the reference;
//!   with `--engines`, the episodes run on engines reachable on Zenoh
//!   ([`ciflow_bridge::spread`]); episodes that replay the checkpoint's demonstrations
//!   (its `training_split.json`) are also counted apart, fitted and held out;
//! - `--nll DATASET`: the flow's log-likelihood per transition on a dataset;
//! - `--field FILE`: for 2-D flows, the vector field, rollouts and latent-grid image.

use std::path::{Path, PathBuf};

use anyhow::Context;
use ciflow_bridge::spread;
use ciflow_engine::flow::{Policy, checkpoint};
use ciflow_envs::actor::{DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::dataset::{self, Episode};
use ciflow_envs::registry::{self, Kwargs, TaskEntry};
use ciflow_evaluation::field::{FieldConfig, field};
use ciflow_evaluation::likelihood::{log_likelihood, scored_episodes};
use ciflow_evaluation::{
    Acting, ContextSwitch, Disturbance, EvaluationConfig, PushConfig, evaluate, summarize,
};
use clap::ValueEnum;
use serde::Serialize;

use ciflow_cli::network::EnginesArgs;
use ciflow_cli::parse::{parse_contexts, parse_key_value, parse_window};
use ciflow_cli::progress;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum PerturbArg {
    None,
    /// A push on the end effector (pouring: the hand; planar tasks: the mass) mid-motion.
    Push,
    /// The context (pot, target, phase) moved mid-motion to a new valid one.
    Context,
}

#[derive(clap::Args, Debug)]
pub struct EvaluateArgs {
    /// Checkpoint directory (a flow or an MLP baseline).
    #[arg(long, required_unless_present = "expert")]
    pub checkpoint: Option<PathBuf>,
    /// Instead of a checkpoint, the episodes of the task's expert (needs --task): the
    /// demonstrator, as the reference for the same disturbances and measures.
    #[arg(long, conflicts_with_all = ["checkpoint", "nll", "field"], requires = "task")]
    pub expert: bool,
    /// Expected task name [default: the checkpoint's]; with --expert, the task whose
    /// expert acts.
    #[arg(long)]
    pub task: Option<String>,
    /// Construction argument of the task, NAME=VALUE (e.g. obstacles=3); repeatable.
    #[arg(long = "kwarg", value_name = "NAME=VALUE", value_parser = parse_key_value)]
    pub kwargs: Vec<(String, String)>,
    /// Reset option of every episode, NAME=VALUE (e.g. context_set=1); repeatable.
    #[arg(long = "option", value_name = "NAME=VALUE", value_parser = parse_key_value)]
    pub options: Vec<(String, String)>,
    /// Number of episodes; episode i is reset with seed + i.
    #[arg(long, default_value_t = 100, conflicts_with_all = ["nll", "field"])]
    pub episodes: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Velocity-feedback gain K_v of the actor (1/s).
    #[arg(long, default_value_t = DEFAULT_VELOCITY_GAIN)]
    pub velocity_gain: f64,
    #[arg(long, value_enum, default_value = "none", conflicts_with_all = ["nll", "field"])]
    pub perturb: PerturbArg,
    /// Push start (simulated s).
    #[arg(long, default_value_t = PushConfig::default().start, requires = "perturb")]
    pub push_start: f64,
    /// Push duration (s).
    #[arg(long, default_value_t = PushConfig::default().duration, requires = "perturb")]
    pub push_duration: f64,
    /// Minimum displacement of the tracked point (pouring: the spout) from the unpushed
    /// run at equal times; the force grows until it is reached (m).
    #[arg(long, default_value_t = PushConfig::default().displacement, requires = "perturb")]
    pub push_displacement: f64,
    /// First push force tried (N).
    #[arg(long, default_value_t = PushConfig::default().initial_force, requires = "perturb")]
    pub push_force: f64,
    /// Link pushed [default: the task's: the hand (last link) for pouring, the mass
    /// otherwise].
    #[arg(long, requires = "perturb")]
    pub push_link: Option<usize>,
    /// Distance to the unpushed path that counts as recovered (m).
    #[arg(long, default_value_t = PushConfig::default().recovery_tolerance, requires = "perturb")]
    pub recovery_tolerance: f64,
    /// Recovery within this time after the push counts as prompt (s).
    #[arg(long, default_value_t = PushConfig::default().recovery_deadline, requires = "perturb")]
    pub recovery_deadline: f64,
    /// Time of the context change (simulated s).
    #[arg(long, default_value_t = 1.0, requires = "perturb")]
    pub switch_time: f64,
    /// Change only the last N context entries [default: the task's: the target (2) for
    /// obstacle-avoidance, the whole context otherwise].
    #[arg(long, requires = "perturb")]
    pub switch_tail: Option<usize>,
    /// Keep the traces of the first K episodes in the JSON.
    #[arg(long, default_value_t = 0, conflicts_with_all = ["nll", "field"])]
    pub trajectories: usize,
    #[command(flatten)]
    pub on: EnginesArgs,
    /// JSON file to write (episodes or --nll); the summary is printed either way.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Instead of episodes: the flow's log-likelihood per transition on this dataset, over
    /// what `ciflow train` fits by default: the episodes that achieved their task, without
    /// the steps an external force moved.
    #[arg(long, conflicts_with = "field")]
    pub nll: Option<PathBuf>,
    /// With --nll: score only the N episodes that `ciflow train --subset N --seed S` drew
    /// for training, with S given as --seed (train log-likelihood of a learning curve).
    #[arg(long, value_name = "N", requires = "nll")]
    pub nll_subset: Option<usize>,
    /// Instead of episodes: write the 2-D flow's vector field, rollouts and latent-grid
    /// image to this JSON file.
    #[arg(long)]
    pub field: Option<PathBuf>,
    /// Contexts of the field figures, `;`-separated, each comma-separated (e.g. "0;0.5;1")
    /// [default: the first 3 episodes' contexts of --field-demos].
    #[arg(long, requires = "field")]
    pub field_contexts: Option<String>,
    /// Dataset whose positions are copied into the field JSON for overlays.
    #[arg(long, requires = "field")]
    pub field_demos: Option<PathBuf>,
    /// Field window x_min,x_max,y_min,y_max (e.g. -60,10,-15,40) [default: the
    /// demonstrations' box, widened].
    #[arg(long, allow_hyphen_values = true, value_parser = parse_window, requires = "field")]
    pub field_window: Option<[f64; 4]>,
    /// Field grid points per axis.
    #[arg(long, default_value_t = 25, requires = "field")]
    pub field_resolution: usize,
    /// Steps of each field rollout.
    #[arg(long, default_value_t = 1000, requires = "field")]
    pub field_steps: usize,
    /// Latent grid lines per axis.
    #[arg(long, default_value_t = 11, requires = "field")]
    pub field_lines: usize,
}

fn write_json(path: &Path, value: &impl Serialize) -> anyhow::Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    std::fs::write(path, serde_json::to_string(value)?)
        .with_context(|| format!("writing {}", path.display()))
}

fn flow(model: &Model) -> anyhow::Result<&Policy> {
    model
        .flow()
        .context("the baseline has no density or latent space")
}

/// The episodes of the dataset at `dir`, which must hold episodes of `task`.
fn read_dataset(dir: &Path, task: &str) -> anyhow::Result<Vec<Episode>> {
    let (spec, episodes) =
        dataset::read(dir).with_context(|| format!("reading {}", dir.display()))?;
    let expected = registry::entry(task)?.id;
    anyhow::ensure!(
        spec.env_id == expected,
        "{} holds episodes of {}; the checkpoint acts in {expected}",
        dir.display(),
        spec.env_id
    );
    Ok(episodes)
}

/// The disturbance the flags ask for in `task` (its defaults where a flag is not given).
fn disturbance(
    args: &EvaluateArgs,
    task: &TaskEntry,
    kwargs: &Kwargs,
) -> anyhow::Result<Disturbance> {
    Ok(match args.perturb {
        PerturbArg::None => Disturbance::None,
        PerturbArg::Push => Disturbance::Push(PushConfig {
            link: match args.push_link {
                Some(link) => link,
                None => task.pushed_link_with(kwargs)?,
            },
            start: args.push_start,
            duration: args.push_duration,
            displacement: args.push_displacement,
            initial_force: args.push_force,
            recovery_tolerance: args.recovery_tolerance,
            recovery_deadline: args.recovery_deadline,
            ..PushConfig::default()
        }),
        PerturbArg::Context => Disturbance::Context(ContextSwitch {
            time: args.switch_time,
            tail: args.switch_tail.or(task.moved_context_tail),
        }),
    })
}

/// `path` made absolute, through its existing parent's real path when it has one (so
/// that `ck/../ck/config.json` and a symlinked directory compare as what they are).
fn resolved(path: &Path) -> PathBuf {
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
    let real_parent = parent.map_or_else(|| Path::new(".").canonicalize(), Path::canonicalize);
    match (real_parent, path.file_name()) {
        (Ok(parent), Some(name)) => parent.join(name),
        _ => std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()),
    }
}

/// Refuses, before any episode runs, a JSON output that is a directory or lies in one of
/// the inputs: `--out CHECKPOINT/config.json` would replace the checkpoint it measures.
fn check_outputs(args: &EvaluateArgs) -> anyhow::Result<()> {
    let inputs: Vec<PathBuf> = [&args.checkpoint, &args.nll, &args.field_demos]
        .into_iter()
        .flatten()
        .map(|dir| resolved(dir))
        .collect();
    for (flag, out) in [("--out", &args.out), ("--field", &args.field)] {
        let Some(out) = out else { continue };
        anyhow::ensure!(
            !out.is_dir(),
            "{flag} {} is a directory; give the path of the JSON file to write",
            out.display()
        );
        let written = resolved(out);
        if let Some(input) = inputs.iter().find(|input| written.starts_with(input)) {
            anyhow::bail!(
                "{flag} {} lies inside the input {}: writing it would replace part of what \
                 is evaluated",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

pub fn run(args: EvaluateArgs) -> anyhow::Result<()> {
    check_outputs(&args)?;
    anyhow::ensure!(
        args.on.engines.is_empty()
            || (args.checkpoint.is_some() && args.nll.is_none() && args.field.is_none()),
        "--engines runs a checkpoint's episodes (--checkpoint, without --nll or --field)"
    );
    let Some(dir) = &args.checkpoint else {
        let task = registry::entry(args.task.as_deref().expect("clap requires --task"))?;
        return episodes(&args, task, Acting::Expert);
    };
    let model = Model::load(dir, args.task.as_deref())
        .with_context(|| format!("loading {}", dir.display()))?;
    if let Some(dir) = &args.nll {
        let count = args.nll_subset.map(|n| (n, args.seed));
        let (episodes, failed) = scored_episodes(read_dataset(dir, model.task())?, count)?;
        if failed > 0 {
            println!("{}: {failed} failed episodes are not scored", dir.display());
        }
        let nll = log_likelihood(flow(&model)?, &episodes)?;
        println!("{}: {nll}", dir.display());
        return args
            .out
            .as_deref()
            .map_or(Ok(()), |out| write_json(out, &nll));
    }
    if let Some(out) = &args.field {
        let demonstrations = match &args.field_demos {
            Some(dir) => read_dataset(dir, model.task())?,
            None => Vec::new(),
        };
        let contexts = match &args.field_contexts {
            Some(text) => parse_contexts(text)
                .map_err(anyhow::Error::msg)
                .context("--field-contexts")?,
            None => demonstrations
                .iter()
                .take(3)
                .filter_map(|e| e.contexts.first().cloned())
                .collect(),
        };
        anyhow::ensure!(
            !contexts.is_empty(),
            "give --field-contexts or --field-demos"
        );
        let config = FieldConfig {
            contexts,
            window: args.field_window,
            resolution: args.field_resolution,
            starts: None,
            rollout_steps: args.field_steps,
            latent_lines: args.field_lines,
        };
        let report = field(flow(&model)?, &config, &demonstrations)?;
        write_json(out, &report)?;
        println!(
            "wrote {}: {} contexts, window {:?}",
            out.display(),
            report.fields.len(),
            report.window
        );
        return Ok(());
    }
    episodes(&args, registry::entry(model.task())?, Acting::Model(&model))
}

/// The closed-loop episodes of `acting` in `task` (the default mode).
/// Without `--kwarg`, a checkpoint acts in the task it recorded (e.g. its URDF arm).
fn episodes(args: &EvaluateArgs, task: &TaskEntry, acting: Acting) -> anyhow::Result<()> {
    let kwargs = match (&acting, args.kwargs.is_empty()) {
        (Acting::Model(model), true) => model.task_kwargs()?,
        _ => task.arguments(&args.kwargs)?,
    };
    let mut env = (task.make_with)(&kwargs).with_context(|| {
        let shown: Vec<_> = kwargs.iter().map(|(k, v)| format!("{k}={v}")).collect();
        format!("building `{}` with {}", task.name, shown.join(", "))
    })?;
    let config = EvaluationConfig {
        episodes: args.episodes,
        seed: args.seed,
        velocity_gain: args.velocity_gain,
        reset_extra: task.values(&args.options)?,
        disturbance: disturbance(args, task, &kwargs)?,
        trajectories: args.trajectories,
    };
    config.validate()?;
    config.fits_episode(env.spec())?;
    // Read before any episode runs: a malformed file must not cost the evaluation.
    let split = match &args.checkpoint {
        Some(dir) => checkpoint::split::read_split(dir)
            .with_context(|| format!("reading the training split of {}", dir.display()))?,
        None => None,
    };
    let progress = progress::bar(args.episodes as u64, "evaluate", "episodes");
    let on_engines = match (acting, &args.checkpoint) {
        (Acting::Model(model), Some(dir)) => {
            args.on.serve_checkpoint(dir, model.task(), &kwargs)?
        }
        _ => None,
    };
    let mut report = match on_engines {
        None => evaluate(env.as_mut(), acting, &config, |done| {
            progress.set_position(done as u64)
        })
        .context("evaluating")?,
        Some(on) => {
            let batches = spread::evaluate(&on.client, &on.engines, &on.policy, &config, |done| {
                progress.set_position(done as u64)
            })
            .context("evaluating on the engines")?;
            summarize(env.spec(), acting, &config, batches)?
        }
    };
    progress.finish_and_clear();
    if let Some(split) = &split {
        report.divide_by(split);
    }
    print!("{report}");
    if let Some(out) = &args.out {
        write_json(out, &report)?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
