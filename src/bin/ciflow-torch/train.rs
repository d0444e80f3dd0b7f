//! `ciflow train`: fit a stable conditioned INN policy to a demonstration dataset by exact
//! maximum likelihood (and, with `--baseline`, the unconstrained behaviour-cloning MLP used
//! as the stability check's negative control).
//!
//! The dataset is the Minari directory `ciflow demos` writes (`envs/DATASET.md`). The
//! policy's state `y` is the position part `q` of each observation `[q, q̇, c]` (planar
//! tasks: the 2-D position; pouring: the 7 joint positions), its context the per-step
//! context `c`, its period the dataset's `control_dt`. With `--from-zenoh N` the
//! demonstrations are collected from recorders over Zenoh instead ([`episodes`]).

mod episodes;

use std::path::PathBuf;

use anyhow::Context;
use ciflow_bridge::CheckpointPublisher;
use ciflow_bridge::error::full_message;
use ciflow_engine::flow::JointRange;
use ciflow_envs::learning_curve::subset;
use ciflow_envs::registry;
use ciflow_train::baseline::{BASELINE_DIR, remove_stale_baseline};
use ciflow_train::dataset::{self, ForeignFields};
use ciflow_train::trainer::{check_checkpoint_dir, flow_config};
use ciflow_train::{
    BaselineTrainConfig, ContextOverrides, Progress, RecipeOverrides, Screening, train_baseline,
    train_flow_into,
};

use ciflow_cli::parse::parse_key_value;
use ciflow_cli::progress;

#[derive(clap::Args, Debug)]
// A negative setting (`--arrival -1`) reaches the check that explains it, instead of
// being taken for a flag.
#[command(allow_negative_numbers = true)]
pub struct TrainArgs {
    /// Task (command-line name or Gymnasium id); recorded in the checkpoint, and the
    /// dataset must have been recorded on it (with --state: its training recipe only).
    #[arg(long)]
    pub task: String,
    /// Dataset directory written by `ciflow demos` (Minari Arrow layout), or with --state
    /// a Minari or LeRobot one made by another tool; with --from-zenoh, where the
    /// collected episodes are written.
    #[arg(long, required_unless_present = "from_zenoh")]
    pub demos: Option<PathBuf>,
    #[command(flatten)]
    pub foreign: ForeignFields,
    #[command(flatten)]
    pub zenoh: episodes::ZenohSource,
    /// Checkpoint directory to write (config.json + weights.safetensors).
    #[arg(long)]
    pub out: PathBuf,
    /// Train on this many of the dataset's episodes (for learning curves against the
    /// amount of data): of as many distinct contexts spread evenly over their range when
    /// the context is one number per episode, else drawn at random with `--seed`
    /// [default: all].
    #[arg(long)]
    pub subset: Option<usize>,
    #[command(flatten)]
    pub context: ContextOverrides,
    #[command(flatten)]
    pub model: RecipeOverrides,
    #[command(flatten)]
    pub screening: Screening,
    /// Also train the behaviour-cloning baseline into `<out>/baseline` (without it, a
    /// baseline an earlier run left there is removed: it would not match the new flow).
    #[arg(long)]
    pub baseline: bool,
    /// Publish each better checkpoint as policy NAME on ciflow/v2/policies/NAME/checkpoint
    /// (through the Zenoh flags above): engines hot-load it and serve it under NAME without
    /// a restart. Nobody listening is not an error; an engine started later loads the
    /// final checkpoint with `ciflow serve --policy NAME=<out>` (`--own-data-policy` for
    /// data from elsewhere, whose running policy it replaces as well).
    #[arg(long, value_name = "NAME")]
    pub publish: Option<String>,
    /// Construction argument of the task the demonstrations were recorded with (e.g.
    /// obstacles=1), sent with each publication so engines build the task the policy acts
    /// in; repeatable.
    #[arg(long = "kwarg", value_name = "NAME=VALUE", value_parser = parse_key_value, requires = "publish")]
    pub kwargs: Vec<(String, String)>,
    #[command(flatten)]
    pub signing: ciflow_bridge::signing::SigningArgs,
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let task = registry::entry(&args.task)?;
    check_checkpoint_dir(&args.out).context("--out")?;
    let converted = args.out.join("demonstrations");
    let foreign = (&args.foreign, converted.as_path());
    let (spec, mut data) = episodes::demonstrations(
        task,
        args.demos.as_deref(),
        foreign,
        &args.zenoh,
        args.screening,
    )?;
    if let Some(count) = args.subset {
        data.episodes = subset(
            data.episodes,
            count,
            args.model.seed.unwrap_or_default(),
            |e| e.context(0),
        )
        .context("--subset")?;
    }
    let recipe = task.training_recipe(spec.context_space.dim())?;
    let robot = match task.robot {
        Some(arm) => Some(JointRange::from_limits(arm(&spec.env_kwargs)?.limits())),
        None => None,
    };
    let mut config = args.model.apply(args.context.apply(recipe)?, robot)?;
    if args.foreign.state.is_some() && args.context.goal_context_indices.is_none() {
        let state_dim = data.episodes.first().map_or(0, |e| e.states[0].len());
        config.goal_context_indices = dataset::foreign_target(
            config.goal_context_indices.take(),
            task.name,
            state_dim,
            spec.context_space.dim(),
        )
        .context("reading the dataset's go-to target")?;
    }
    // The checkpoint builds the same task (and robot) the demonstrations were made in.
    config.task_kwargs = ciflow_envs::kwargs::to_json(&spec.env_kwargs);
    // Everything training would refuse, before the checkpoint directory is touched.
    flow_config(&data, &config).context("checking the training settings")?;
    let target = match &config.goal_context_indices {
        Some(indices) => format!("the target at context entries {indices:?}"),
        None => "no target in the context".to_owned(),
    };
    let sets: Vec<String> = config.context_sets.iter().map(|s| s.to_string()).collect();
    let sets = match sets.is_empty() {
        true => "no unordered context sets".to_owned(),
        false => format!("unordered context sets: {}", sets.join("; ")),
    };
    let contractions = match &config.contractions {
        Some(c) => format!("{} radial contraction layers about {}", c.layers, c.centres),
        None => "no radial contractions".to_owned(),
    };
    println!(
        "{}: {} episodes, state {}-D, context {}-D, dt = {} s; latent {:?}, {target}, {sets}, \
         {contractions}",
        spec.dataset_id,
        data.episodes.len(),
        data.episodes.first().map_or(0, |e| e.states[0].len()),
        spec.context_space.dim(),
        data.dt,
        config.latent,
    );
    let publisher = args
        .publish
        .as_deref()
        .map(|name| {
            let kwargs = task.arguments(&args.kwargs)?;
            // Engines build the task from these: arguments it refuses would have every
            // engine ignore each publication, while this side reported them sent.
            (task.make_with)(&kwargs).context("--kwarg")?;
            let network = args.zenoh.network.options()?;
            let publisher = CheckpointPublisher::open(&network, name)?.with_kwargs(kwargs);
            anyhow::Ok(publisher.with_signer(args.signing.load()?))
        })
        .transpose()
        .context("--publish")?;
    remove_stale_baseline(&args.out)?;
    let bar = progress::bar(config.optim.epochs as u64, "flow", "epochs");
    let on_epoch = |p: &Progress| {
        bar.set_position(p.epoch as u64);
        bar.set_message(format!(
            "loss {:.3} val NLL/transition {:.3}",
            p.train_loss, p.validation
        ));
    };
    // Publishing is a convenience for running engines, the file the record: a failed
    // publication is reported and training goes on.
    let publish = |p: &Progress| {
        if let Some(publisher) = &publisher
            && let Err(error) = publisher.publish(&args.out, p.epoch as u64, p.validation)
        {
            let name = publisher.name();
            eprintln!(
                "warning: epoch {}: publishing policy `{name}` failed: {}",
                p.epoch,
                full_message(&error)
            );
        }
    };
    let trained = train_flow_into(&args.out, &data, &config, on_epoch, publish)
        .with_context(|| format!("training the flow into {}", args.out.display()))?;
    bar.finish();
    if let Some(publisher) = &publisher {
        println!(
            "published policy `{}` (epoch {})",
            publisher.name(),
            trained.best_epoch
        );
    }
    let best = trained
        .history
        .iter()
        .map(|p| p.validation)
        .fold(f64::INFINITY, f64::min);
    println!(
        "flow: best validation NLL per transition {best:.4} (epoch {}), checkpoint {}",
        trained.best_epoch,
        args.out.display()
    );

    if args.baseline {
        let bar = progress::bar(config.optim.epochs as u64, "baseline", "epochs");
        let baseline = train_baseline(
            &data,
            &BaselineTrainConfig::matching(&config, &data),
            |p: &Progress| {
                bar.set_position(p.epoch as u64);
                bar.set_message(format!(
                    "loss {:.4} val MSE {:.4}",
                    p.train_loss, p.validation
                ));
            },
        )
        .context("training the baseline")?;
        bar.finish();
        let dir = args.out.join(BASELINE_DIR);
        baseline
            .save(&dir)
            .with_context(|| format!("writing {}", dir.display()))?;
        // Without held-out episodes the training loss stands in for the validation score.
        let scored_on = match baseline.split.held_out.is_empty() {
            true => "the fitted episodes",
            false => "the held-out episodes",
        };
        println!(
            "baseline: epoch {} kept, velocity MSE {:.4} on {scored_on} (normalised), checkpoint {}",
            baseline.best_epoch,
            baseline.history[baseline.best_epoch - 1].validation,
            dir.display()
        );
    }
    Ok(())
}
