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

use std::path::{Path, PathBuf};

use anyhow::Context;
use ciflow_bridge::CheckpointPublisher;
use ciflow_engine::flow::{
    ContextSet, ContractionConfig, CouplingKind, LatentKind, LocalConfig, SetEncoderConfig,
};
use ciflow_envs::learning_curve::subset;
use ciflow_envs::registry;
use ciflow_train::{
    BaselineTrainConfig, Keep, OptimConfig, Progress, Screening, Snapshot, TrainConfig,
    train_baseline, train_flow,
};
use clap::ValueEnum;

use super::demos::{parse_key_value, task_values};
use crate::progress;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LatentArg {
    /// Fixed-point attractor.
    GoTo,
    /// Fixed-point attractor approached at bounded speed.
    SaturatedGoTo,
    /// Limit cycle in the first two latent dimensions.
    LimitCycle,
}

impl From<LatentArg> for LatentKind {
    fn from(latent: LatentArg) -> Self {
        match latent {
            LatentArg::GoTo => LatentKind::GoTo,
            LatentArg::SaturatedGoTo => LatentKind::SaturatedGoTo,
            LatentArg::LimitCycle => LatentKind::LimitCycle,
        }
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum CouplingArg {
    /// Affine coupling with tanh-bounded log-scale.
    Affine,
    /// Rational-quadratic spline coupling with identity tails.
    Spline,
}

impl CouplingArg {
    fn is_spline(self) -> bool {
        matches!(self, Self::Spline)
    }
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum KeepArg {
    /// The epoch with the best validation score (early stopping).
    BestValidation,
    /// The last epoch's.
    Last,
}

impl From<KeepArg> for Keep {
    fn from(keep: KeepArg) -> Self {
        match keep {
            KeepArg::BestValidation => Keep::BestValidation,
            KeepArg::Last => Keep::Last,
        }
    }
}

/// Architecture and optimisation settings shared by every command that trains policies.
/// Those marked "the task's" default to the task's recipe (`TaskEntry::training_recipe`).
#[derive(clap::Args, Debug, Clone)]
pub struct ModelArgs {
    /// Latent attractor [default: the task's: limit-cycle for limit-cycle, saturated-go-to
    /// for lasa, else go-to].
    #[arg(long, value_enum)]
    pub latent: Option<LatentArg>,
    /// Coupling layers [default: the task's: affine for lasa and pouring, else spline].
    #[arg(long, value_enum)]
    pub coupling: Option<CouplingArg>,
    /// Bins of each spline coupling [default: the task's spline's, else 8].
    #[arg(long)]
    pub spline_bins: Option<usize>,
    /// Half-width `B` of the spline's interval `[-B, B]` (normalised units; identity
    /// outside) [default: the task's spline's, else 4].
    #[arg(long)]
    pub tail_bound: Option<f64>,
    /// Number of (mixing, coupling) blocks [default: the task's: 10 for lasa and pouring,
    /// else 6].
    #[arg(long)]
    pub layers: Option<usize>,
    /// Hidden widths of each conditioner MLP, comma-separated [default: the task's: 32,32
    /// for lasa, else 64,64].
    #[arg(long, value_delimiter = ',')]
    pub hidden: Option<Vec<usize>>,
    /// Guaranteed latent contraction rate (1/s) [default: the task's: 1 for go-to tasks,
    /// whose demonstrations arrive within 2–9 s; 0.2 for lasa, whose saturated latent
    /// keeps its constant pace only where it is faster than this rate; 0.1 for the limit
    /// cycle].
    #[arg(long)]
    pub min_rate: Option<f64>,
    /// Gaussian jitter added to training states, as a fraction of the demonstrations' RMS
    /// step; gives deterministic (expert) demonstrations a bounded likelihood; 0 trains
    /// on the states as recorded (exact maximum likelihood) [default: the task's: 0 for
    /// lasa, else 0.1].
    #[arg(long)]
    pub state_noise: Option<f64>,
    /// Longest modelled transition: each training pair spans k ~ U{1..K} steps, scored
    /// with the exact k-step density (1: one-step transitions) [default: the task's: 40
    /// for lasa, else 1].
    #[arg(long)]
    pub horizon: Option<usize>,
    /// Share of the training pairs whose span runs to the end of their demonstration
    /// (0: none) [default: the task's: 0.25 for lasa, else 0].
    #[arg(long)]
    pub arrival: Option<f64>,
    /// Fraction of the demonstrations held out for early stopping (0: fit all of them,
    /// the training loss stands in for the validation score) [default: the task's: 0 for
    /// lasa, pouring and the limit cycle, else 0.2].
    #[arg(long)]
    pub validation_fraction: Option<f64>,
    /// Epoch budget [default: the task's: 30 for lasa, 6 for pouring, else 200].
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Training pairs per step [default: the task's: 512 for pouring, else 256].
    #[arg(long)]
    pub batch_size: Option<usize>,
    #[arg(long, default_value_t = 2e-3)]
    pub learning_rate: f64,
    /// Early-stopping patience in epochs.
    #[arg(long, default_value_t = 30)]
    pub patience: usize,
    /// Which epoch's parameters to keep [default: the task's: last for lasa, pouring and
    /// the limit cycle, else best-validation].
    #[arg(long, value_enum)]
    pub keep: Option<KeepArg>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// libtorch threads.
    #[arg(long, default_value_t = 1)]
    pub threads: i32,
}

impl ModelArgs {
    /// The flow's training configuration: `recipe` (the task's) with what the command line
    /// sets in its place.
    /// The spline flags apply to whichever spline the coupling is; with an affine one they
    /// are an error rather than silently ignored.
    pub fn flow(&self, recipe: TrainConfig) -> anyhow::Result<TrainConfig> {
        let (bins, tail_bound) = match recipe.coupling {
            CouplingKind::Spline { bins, tail_bound } => (bins, tail_bound),
            CouplingKind::Affine { .. } => (8, 4.0),
        };
        let spline = CouplingKind::Spline {
            bins: self.spline_bins.unwrap_or(bins),
            tail_bound: self.tail_bound.unwrap_or(tail_bound),
        };
        let coupling = match self.coupling.map(CouplingArg::is_spline) {
            None if matches!(recipe.coupling, CouplingKind::Spline { .. }) => spline,
            Some(true) => spline,
            None | Some(false) => {
                if self.spline_bins.is_some() || self.tail_bound.is_some() {
                    anyhow::bail!(
                        "--spline-bins and --tail-bound set a spline coupling, and this one is \
                         affine (add --coupling spline)"
                    );
                }
                match self.coupling {
                    Some(_) => CouplingKind::AFFINE,
                    None => recipe.coupling,
                }
            }
        };
        Ok(TrainConfig {
            latent: self.latent.map_or(recipe.latent, LatentKind::from),
            coupling,
            layers: self.layers.unwrap_or(recipe.layers),
            hidden: self.hidden.clone().unwrap_or(recipe.hidden),
            min_rate: self.min_rate.unwrap_or(recipe.min_rate),
            horizon: self.horizon.unwrap_or(recipe.horizon),
            arrival: self.arrival.unwrap_or(recipe.arrival),
            state_noise: self.state_noise.unwrap_or(recipe.state_noise),
            validation_fraction: self
                .validation_fraction
                .unwrap_or(recipe.validation_fraction),
            threads: self.threads,
            optim: OptimConfig {
                epochs: self.epochs.unwrap_or(recipe.optim.epochs),
                batch_size: self.batch_size.unwrap_or(recipe.optim.batch_size),
                learning_rate: self.learning_rate,
                patience: self.patience,
                keep: self.keep.map_or(recipe.optim.keep, Keep::from),
                seed: self.seed,
                ..recipe.optim
            },
            ..recipe
        })
    }
}

#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Task (command-line name or Gymnasium id); recorded in the checkpoint, and the
    /// dataset must have been recorded on it.
    #[arg(long)]
    pub task: String,
    /// Dataset directory written by `ciflow demos` (Minari Arrow layout); with
    /// --from-zenoh, where the collected episodes are written.
    #[arg(long, required_unless_present = "from_zenoh")]
    pub demos: Option<PathBuf>,
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
    /// Context indices holding the go-to target (one per state dimension),
    /// comma-separated [default: the task's: the target of obstacle-avoidance, the goal
    /// of lasa, none otherwise].
    #[arg(long, value_delimiter = ',')]
    pub goal_context_indices: Option<Vec<usize>>,
    /// Unordered sets in the context, which the conditioners see through a
    /// permutation-invariant set encoder: START:COUNT:SIZE (COUNT elements of SIZE entries from context index
    /// START), comma-separated, or `none` [default: the task's: the obstacle centres of
    /// obstacle-avoidance, none otherwise].
    #[arg(long, value_delimiter = ',', value_parser = parse_context_set)]
    pub context_sets: Option<Vec<Option<ContextSet>>>,
    /// Radial contraction layers about the obstacle centres in front of the network (0:
    /// none) [default: the task's: 8 for obstacle-avoidance; other tasks have no
    /// centres to contract about].
    #[arg(long)]
    pub contraction_layers: Option<usize>,
    /// Width `W_ψ` of the local features each coupling pools over every context set,
    /// from a network with one hidden layer of `2 W_ψ` (0: none; the set encoder's
    /// summary alone) [default: the set encoder's].
    #[arg(long)]
    pub local_features: Option<usize>,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Also train on demonstrations that failed their task (their last step is not a
    /// success: spilled, collided, never arrived); by default they are dropped.
    #[arg(long)]
    pub keep_failed: bool,
    /// Also fit the steps an external force moved (flagged `perturbed` in the data); by
    /// default they are left out of the likelihood, so the policy does not learn the push
    /// as its own motion.
    #[arg(long)]
    pub keep_perturbed: bool,
    /// Also leave out this many seconds after each pushed step, while the velocity the
    /// push left decays (the pouring expert's twist loop, 12 /s, takes 0.38 s to 1 %).
    /// Those steps are the expert's response to the pushed state, what pushed
    /// demonstrations are recorded to teach: leaving them out cost the pouring policy
    /// most of its recovery from pushes (README "Pouring").
    #[arg(long, default_value_t = 0.0, value_name = "SECONDS")]
    pub push_settling: f64,
    /// Also train the behaviour-cloning baseline into `<out>/baseline`.
    #[arg(long)]
    pub baseline: bool,
    /// Publish each better checkpoint as policy NAME on ciflow/v1/policies/NAME/checkpoint
    /// (through the Zenoh flags above): engines hot-load it and serve it under NAME without
    /// a restart. Nobody listening is not an error; an engine started later loads the
    /// final checkpoint with `ciflow serve --policy NAME=<out>`.
    #[arg(long, value_name = "NAME")]
    pub publish: Option<String>,
    /// Construction argument of the task the demonstrations were recorded with (e.g.
    /// obstacles=1), sent with each publication so engines build the task the policy acts
    /// in; repeatable.
    #[arg(long = "kwarg", value_name = "NAME=VALUE", value_parser = parse_key_value, requires = "publish")]
    pub kwargs: Vec<(String, String)>,
}

/// `START:COUNT:SIZE` as a [`ContextSet`], `none` as no set.
fn parse_context_set(text: &str) -> Result<Option<ContextSet>, String> {
    if text == "none" {
        return Ok(None);
    }
    let fields: Vec<usize> = text
        .split(':')
        .map(|f| f.parse().map_err(|e| format!("`{f}`: {e}")))
        .collect::<Result<_, _>>()?;
    match fields[..] {
        [start, count, size] => Ok(Some(ContextSet { start, count, size })),
        _ => Err(format!("`{text}` is not START:COUNT:SIZE or `none`")),
    }
}

/// Writes a better checkpoint to `out` (an interrupted run keeps its best so far) and
/// publishes it. A failed publication is reported and training goes on: the file is the
/// record, the publication a convenience for running engines.
fn keep_checkpoint(
    snapshot: &Snapshot,
    out: &Path,
    publisher: Option<&CheckpointPublisher>,
    progress: &Progress,
) -> anyhow::Result<()> {
    snapshot
        .save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    if let Some(publisher) = publisher
        && let Err(error) = publisher.publish(out, progress.epoch as u64, progress.validation)
    {
        eprintln!(
            "warning: epoch {}: publishing policy `{}` failed: {error}",
            progress.epoch,
            publisher.name()
        );
    }
    Ok(())
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let task = registry::entry(&args.task)?;
    let screening = Screening {
        keep_failed: args.keep_failed,
        keep_perturbed: args.keep_perturbed,
        push_settling: args.push_settling,
    };
    let (spec, mut data) =
        episodes::demonstrations(task, args.demos.as_deref(), &args.zenoh, screening)?;
    if let Some(count) = args.subset {
        data.episodes =
            subset(data.episodes, count, args.model.seed, |e| e.context(0)).context("--subset")?;
    }
    let recipe = task.training_recipe(spec.context_space.dim())?;
    let recipe = TrainConfig {
        goal_context_indices: args
            .goal_context_indices
            .clone()
            .or(recipe.goal_context_indices),
        context_sets: match &args.context_sets {
            Some(sets) => sets.iter().flatten().copied().collect(),
            None => recipe.context_sets,
        },
        contractions: match (args.contraction_layers, recipe.contractions) {
            (Some(0), _) => None,
            (Some(layers), Some(contractions)) => Some(ContractionConfig {
                layers,
                ..contractions
            }),
            (Some(_), None) => {
                anyhow::bail!("--contraction-layers: task `{}` has no centres", task.name)
            }
            (None, contractions) => contractions,
        },
        set_encoder: match args.local_features {
            Some(0) => SetEncoderConfig {
                local: None,
                ..recipe.set_encoder
            },
            Some(width) => SetEncoderConfig {
                local: Some(LocalConfig {
                    hidden: vec![2 * width],
                    width,
                }),
                ..recipe.set_encoder
            },
            None => recipe.set_encoder,
        },
        ..recipe
    };
    let config = args.model.flow(recipe)?;
    let (latent, goal_context_indices) = (config.latent, &config.goal_context_indices);
    println!(
        "{}: {} episodes, state {}-D, context {}-D, dt = {} s; latent {latent:?}, target in \
         context {goal_context_indices:?}, unordered context sets {:?}, contractions {:?}",
        spec.dataset_id,
        data.episodes.len(),
        data.episodes.first().map_or(0, |e| e.states[0].len()),
        spec.context_space.dim(),
        data.dt,
        config.context_sets,
        config.contractions
    );
    let publisher = args
        .publish
        .as_deref()
        .map(|name| {
            let kwargs = task_values(task, args.kwargs.clone())?;
            let network = args.zenoh.network.options()?;
            anyhow::Ok(CheckpointPublisher::open(&network, name)?.with_kwargs(kwargs))
        })
        .transpose()
        .context("--publish")?;
    let bar = progress::bar(config.optim.epochs as u64, "flow", "epochs");
    // The last epoch written to --out (and published): the first one always improves.
    let mut kept_epoch = Ok(0);
    let trained = train_flow(&data, &config, |p: &Progress, snapshot: &Snapshot| {
        bar.set_position(p.epoch as u64);
        bar.set_message(format!(
            "loss {:.3} val NLL/transition {:.3}",
            p.train_loss, p.validation
        ));
        if p.improved && kept_epoch.is_ok() {
            kept_epoch =
                keep_checkpoint(snapshot, &args.out, publisher.as_ref(), p).map(|()| p.epoch);
        }
    })
    .context("training the flow")?;
    let kept_epoch = kept_epoch?;
    bar.finish();
    // With --keep last the parameters kept need not be the last ones written.
    if trained.best_epoch != kept_epoch {
        trained
            .save(&args.out)
            .with_context(|| format!("writing {}", args.out.display()))?;
        if let Some(publisher) = &publisher {
            let kept = trained
                .history
                .get(trained.best_epoch.wrapping_sub(1))
                .context("training ran no epoch")?;
            publisher
                .publish(&args.out, kept.epoch as u64, kept.validation)
                .with_context(|| format!("publishing policy `{}`", publisher.name()))?;
        }
    }
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
        let dir = args.out.join("baseline");
        baseline
            .save(&dir)
            .with_context(|| format!("writing {}", dir.display()))?;
        println!("baseline: checkpoint {}", dir.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::ModelArgs;
    use ciflow_engine::flow::CouplingKind;
    use ciflow_envs::registry;
    use ciflow_train::Keep;
    use clap::Parser;

    #[derive(Parser)]
    struct Flags {
        #[command(flatten)]
        model: ModelArgs,
    }

    /// The training configuration of `task` under command-line `flags`.
    fn configured(task: &str, flags: &[&str]) -> ciflow_train::TrainConfig {
        let flags = Flags::try_parse_from([&["train"][..], flags].concat()).unwrap();
        let recipe = registry::entry(task).unwrap().training_recipe(6).unwrap();
        flags.model.flow(recipe).unwrap()
    }

    #[test]
    fn the_task_recipes_are_the_defaults_and_every_flag_overrides_them() {
        let default = configured("pouring", &[]);
        assert!(matches!(default.coupling, CouplingKind::Affine { .. }));
        assert_eq!(default.layers, 10);
        assert_eq!(default.validation_fraction, 0.0);
        assert_eq!(default.optim.keep, Keep::Last);
        assert_eq!((default.optim.epochs, default.optim.batch_size), (6, 512));
        let flagged = configured(
            "pouring",
            &[
                "--batch-size",
                "64",
                "--epochs",
                "2",
                "--validation-fraction",
                "0.1",
            ],
        );
        assert_eq!((flagged.optim.batch_size, flagged.optim.epochs), (64, 2));
        assert_eq!(flagged.validation_fraction, 0.1);
        // Another go-to task keeps the generic defaults.
        let generic = configured("obstacle-avoidance", &[]);
        assert_eq!(
            (generic.optim.batch_size, generic.validation_fraction),
            (256, 0.2)
        );
    }
}
