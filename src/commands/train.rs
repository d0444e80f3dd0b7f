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
    ContextSet, ContractionConfig, CouplingKind, Goal, LatentKind, LocalConfig, SetEncoderConfig,
};
use ciflow_envs::dataset::{self, DatasetSpec};
use ciflow_envs::registry::{self, TaskEntry};
use ciflow_envs::tasks::{lasa, limit_cycle, obstacle_avoidance, pouring};
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, Keep, OptimConfig, Progress, Snapshot,
    TrainConfig, train_baseline, train_flow,
};
use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};

use super::demos::{parse_key_value, task_values};

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
/// Those marked "the task's" default to the task's recipe ([`task_recipe`]).
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
                    Some(_) => AFFINE_COUPLING,
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

/// The guaranteed latent rate of the limit cycle's linear dimensions (1/s).
const LIMIT_CYCLE_MIN_RATE: f64 = 0.1;
/// The guaranteed latent rate of go-to tasks (1/s). Their demonstrations arrive within
/// 2–9 s; a floor of 1 /s lets the flow arrive in time without having to learn all of its
/// speed from a slow start. Measured against 0.1 /s: LASA `Angle` DTW 1.9 mm against
/// 5.3 mm after 30 epochs; obstacle avoidance (3 obstacles, 60 demonstrations, 8 epochs)
/// 67% of 100 random contexts reached against 3%.
const GO_TO_MIN_RATE: f64 = 1.0;

/// Radial contraction layers about the obstacle centres ([`ciflow_engine::flow::radial`])
/// and the exponent `m` of their profile. A layer pulls by at most `α / K` about each of
/// the `K` centres (what keeps it a bijection when centres coincide), so the layers
/// compound: with 3 obstacles (1000 demonstrations, 2 epochs) 8 layers reached the goal
/// in 100% of 100 new contexts, 6 layers with a weaker initial strength in 97%.
const OBSTACLE_CONTRACTION_LAYERS: usize = 8;
const OBSTACLE_CONTRACTION_EXPONENT: u32 = 2;
/// LASA's guaranteed latent rate (1/s): its strokes last 2–6 s.
const LASA_MIN_RATE: f64 = 0.2;
/// The affine coupling of `--coupling affine` and of the recipes that use one.
const AFFINE_COUPLING: CouplingKind = CouplingKind::Affine { scale_bound: 2.0 };

/// `recipe` fitted to every demonstration it is given, none held out for early stopping,
/// with the last epoch's parameters kept (the training loss stands in for the validation
/// score): for tasks whose held-out contexts are scored elsewhere, or whose every
/// demonstration is a context of its own.
fn fitting_every_demonstration(recipe: TrainConfig) -> TrainConfig {
    TrainConfig {
        validation_fraction: 0.0,
        optim: OptimConfig {
            keep: Keep::Last,
            ..recipe.optim
        },
        ..recipe
    }
}

/// LASA's recipe: what made the stable flow as accurate as the unconstrained baseline
/// and ImitationFlow on the handwriting shapes (`ciflow lasa --ablation` measures each
/// choice). A saturated go-to latent (strokes move at their pace, then settle) whose
/// guaranteed rate is low enough (0.2 /s) to leave the demonstrations in its constant-pace
/// regime; spans of up to 40 steps scored with their k-step density (a one-step density
/// can be matched by a field that cuts corners) and a quarter of them running to the
/// demonstration's end (so the motion arrives when the demonstrations do); the states as
/// recorded (no jitter); all seven demonstrations fitted for a fixed budget of 30 epochs;
/// 10 affine blocks with 32-32 conditioners (as deep as ImitationFlow's).
fn lasa_recipe(recipe: TrainConfig) -> TrainConfig {
    fitting_every_demonstration(TrainConfig {
        latent: LatentKind::SaturatedGoTo,
        min_rate: LASA_MIN_RATE,
        coupling: AFFINE_COUPLING,
        layers: 10,
        hidden: vec![32, 32],
        horizon: 40,
        arrival: 0.25,
        state_noise: 0.0,
        optim: OptimConfig {
            epochs: 30,
            ..recipe.optim
        },
        ..recipe
    })
}

/// Pouring's recipe: 10 affine blocks, 6 epochs of batches of 512 over every successful
/// demonstration, the last epoch kept. None is held out: the held-out contexts are scored
/// on a separate recording, and on 216 pushed demonstrations fitting all of them gave
/// 95–99 % success over three training seeds where early stopping on a 20 % hold-out gave
/// 94–96 % (README "Pouring").
fn pouring_recipe(recipe: TrainConfig) -> TrainConfig {
    fitting_every_demonstration(TrainConfig {
        coupling: AFFINE_COUPLING,
        layers: 10,
        optim: OptimConfig {
            epochs: 6,
            batch_size: 512,
            ..recipe.optim
        },
        ..recipe
    })
}

/// How `task`'s policy is shaped and trained unless the command line says otherwise, for
/// a context of dimension `context_dim`: a limit cycle for the limit-cycle task; go-to
/// elsewhere, with the target read from the context where the task puts it there
/// (obstacle avoidance: its last two entries, `[…, g_x, g_y]`; LASA: the goal
/// `[g_x, g_y]`); pouring's attractor is learned as `f(0, c)`. The obstacle centres
/// `[o₁, …, o_K]` of obstacle avoidance form an unordered set.
pub fn task_recipe(task: &TaskEntry, context_dim: usize) -> anyhow::Result<TrainConfig> {
    let go_to = |goal_context_indices| TrainConfig {
        goal_context_indices,
        min_rate: GO_TO_MIN_RATE,
        ..TrainConfig::new(task.name, LatentKind::GoTo)
    };
    let planar_target = || match context_dim.checked_sub(2) {
        Some(x) => Ok(Some(vec![x, x + 1])),
        None => anyhow::bail!(
            "task `{}` needs its 2-D target in the context, found a {context_dim}-D context",
            task.name
        ),
    };
    Ok(match task.id {
        // Every demonstration is a phase of its own: none is held out of the fit (a
        // learning curve's n counts the phases fitted).
        limit_cycle::ID => fitting_every_demonstration(TrainConfig {
            min_rate: LIMIT_CYCLE_MIN_RATE,
            ..TrainConfig::new(task.name, LatentKind::LimitCycle)
        }),
        obstacle_avoidance::ID => {
            let obstacles = ContextSet {
                start: 0,
                count: (context_dim - 2) / 2,
                size: 2,
            };
            TrainConfig {
                context_sets: vec![obstacles],
                contractions: Some(ContractionConfig {
                    centres: obstacles,
                    layers: OBSTACLE_CONTRACTION_LAYERS,
                    exponent: OBSTACLE_CONTRACTION_EXPONENT,
                    radius: obstacle_avoidance::SAFETY_RADIUS,
                }),
                ..go_to(planar_target()?)
            }
        }
        lasa::ID => lasa_recipe(go_to(planar_target()?)),
        pouring::ID => pouring_recipe(go_to(None)),
        _ => go_to(None),
    })
}

/// Reads a `ciflow demos` dataset of `task` as the policy's demonstrations (see
/// [`to_demonstrations`]).
pub fn read_demonstrations(
    dir: &Path,
    task: &TaskEntry,
    screening: Screening,
) -> anyhow::Result<(DatasetSpec, Demonstrations)> {
    let (spec, episodes) =
        dataset::read(dir).with_context(|| format!("reading the dataset {}", dir.display()))?;
    to_demonstrations(spec, episodes, task, &dir.display().to_string(), screening)
}

/// What of a dataset the trainer leaves out by default, and what the flags keep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Screening {
    /// Demonstrations that failed their task (spilled, collided, never arrived) show
    /// what not to do: dropped unless kept.
    pub keep_failed: bool,
    /// Steps an external force moved show the push, not the expert: left out of the
    /// likelihood unless kept…
    pub keep_perturbed: bool,
    /// …and so are the steps this long after each, s.
    pub push_settling: f64,
}

/// The policy's demonstrations of `task` in dataset episodes (from `source`, for errors):
/// positions `q` of each observation `[q, q̇, c]`, the per-step contexts,
/// `dt = control_dt`; the steps an external force moved are excluded from the likelihood
/// and episodes whose last step is not a success are dropped, unless `screening` keeps
/// them. Prints what was left out.
pub fn to_demonstrations(
    spec: DatasetSpec,
    episodes: Vec<dataset::Episode>,
    task: &TaskEntry,
    source: &str,
    screening: Screening,
) -> anyhow::Result<(DatasetSpec, Demonstrations)> {
    anyhow::ensure!(
        spec.env_id == task.id,
        "{source} holds demonstrations of `{}` ({}), not of task `{}` ({})",
        spec.env_id,
        spec.dataset_id,
        task.name,
        task.id
    );
    let (observation_dim, context_dim) = (spec.observation_space.dim(), spec.context_space.dim());
    let velocity_and_position = observation_dim.saturating_sub(context_dim);
    anyhow::ensure!(
        velocity_and_position > 0 && velocity_and_position % 2 == 0,
        "{}: observations of dimension {observation_dim} with a {context_dim}-D context are \
         not [q, q̇, c]",
        source
    );
    let position_dim = velocity_and_position / 2;
    let recorded = episodes.len();
    let failures = episodes.iter().filter(|e| e.failed()).count();
    let kept: Vec<dataset::Episode> = episodes
        .into_iter()
        .filter(|e| screening.keep_failed || !e.failed())
        .collect();
    anyhow::ensure!(
        !kept.is_empty(),
        "{source}: all {recorded} episodes failed their task; --keep-failed trains on them"
    );
    let transitions: usize = kept.iter().map(dataset::Episode::len).sum();
    let mut perturbed = 0;
    // A step is excluded when it or one of the `settling` steps before it was pushed.
    let settling = (screening.push_settling / spec.control_dt).round() as usize;
    let episodes: Vec<Episode> = kept
        .into_iter()
        .map(|episode| {
            let pushed: Vec<bool> = (0..episode.len()).map(|t| episode.perturbed(t)).collect();
            perturbed += pushed.iter().filter(|&&p| p).count();
            Episode {
                excluded: (0..pushed.len())
                    .map(|t| {
                        !screening.keep_perturbed
                            && pushed[t.saturating_sub(settling)..=t].contains(&true)
                    })
                    .collect(),
                states: episode
                    .observations
                    .iter()
                    .map(|o| o[..position_dim].to_vec())
                    .collect(),
                contexts: Contexts::PerStep(episode.contexts),
            }
        })
        .collect();
    let excluded: usize = episodes
        .iter()
        .map(|e| e.excluded.iter().filter(|&&x| x).count())
        .sum();
    println!(
        "{source}: {failures} of {recorded} episodes failed their task{}; {perturbed} of \
         {transitions} transitions moved by an external force{}; {excluded} left out of the \
         likelihood",
        match (screening.keep_failed, failures) {
            (false, 0) => "",
            (false, _) => " and are dropped (--keep-failed keeps them)",
            (true, _) => ", kept (--keep-failed)",
        },
        match (screening.keep_perturbed, settling) {
            (true, _) => ", kept (--keep-perturbed)".to_string(),
            (false, 0) => String::new(),
            (false, steps) => format!(" (+ {steps} settling steps after each)"),
        }
    );
    let data = Demonstrations {
        episodes,
        dt: spec.control_dt,
    };
    Ok((spec, data))
}

/// `count` of `episodes`, in their original order, for learning curves against the amount
/// of data. Where every episode has one context number (the limit cycle's phase) and
/// there are at least `count` distinct ones, the episodes of `count` distinct values spread
/// evenly over their range, both ends included (2 → the lowest and the highest), so more
/// data means more contexts and never a repeat; otherwise drawn without replacement by a
/// generator seeded with `seed`.
pub(crate) fn subset<T>(
    episodes: Vec<T>,
    count: usize,
    seed: u64,
    context: impl Fn(&T) -> &[f64],
) -> anyhow::Result<Vec<T>> {
    let available = episodes.len();
    anyhow::ensure!(
        (1..=available).contains(&count),
        "asked for {count} episodes, the dataset holds {available}"
    );
    let mut keep = vec![false; available];
    let mut values: Vec<f64> = episodes
        .iter()
        .filter_map(|e| match context(e) {
            [value] => Some(*value),
            _ => None,
        })
        .collect();
    values.sort_by(f64::total_cmp);
    values.dedup();
    let scalar_contexts = episodes.iter().all(|e| context(e).len() == 1);
    if scalar_contexts && values.len() >= count {
        let last = values.len() - 1;
        for i in 0..count {
            let wanted = values[(i * last + (count - 1) / 2) / (count - 1).max(1)];
            let first = episodes.iter().position(|e| context(e)[0] == wanted);
            keep[first.expect("the value came from an episode")] = true;
        }
    } else {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        for i in rand::seq::index::sample(&mut rng, available, count) {
            keep[i] = true;
        }
    }
    Ok(episodes
        .into_iter()
        .zip(keep)
        .filter_map(|(episode, kept)| kept.then_some(episode))
        .collect())
}

/// A bar over `epochs` epochs, prefixed with `what`.
fn epoch_bar(epochs: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(epochs as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} epochs {msg} ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_owned());
    bar
}

/// The demonstrations' mean final state: the go-to goal when the context does not hold it.
fn mean_final_state(data: &Demonstrations) -> Vec<f64> {
    let n = data.episodes.len() as f64;
    let d = data.episodes.first().map_or(0, |e| e.states[0].len());
    let mut goal = vec![0.0; d];
    for e in &data.episodes {
        if let Some(last) = e.states.last() {
            for (g, v) in goal.iter_mut().zip(last) {
                *g += v / n;
            }
        }
    }
    goal
}

/// Where the baseline's rollouts should end, as the flow's target is configured.
fn baseline_goal(goal_context_indices: &Option<Vec<usize>>, data: &Demonstrations) -> Goal {
    match goal_context_indices {
        Some(indices) => Goal::ContextIndices {
            indices: indices.clone(),
        },
        None => Goal::State {
            value: mean_final_state(data),
        },
    }
}

/// The baseline's training configuration: the budget, widths and validation split of `flow`.
pub fn baseline_config(flow: &TrainConfig, goal: Goal) -> BaselineTrainConfig {
    BaselineTrainConfig {
        task: flow.task.clone(),
        hidden: flow.hidden.clone(),
        goal,
        validation_fraction: flow.validation_fraction,
        threads: flow.threads,
        optim: flow.optim.clone(),
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
    anyhow::ensure!(
        args.push_settling.is_finite() && args.push_settling >= 0.0,
        "--push-settling must be a finite number of seconds >= 0, not {}",
        args.push_settling
    );
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
    let recipe = task_recipe(task, spec.context_space.dim())?;
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
    let bar = epoch_bar(config.optim.epochs, "flow");
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
        let goal = baseline_goal(goal_context_indices, &data);
        let bar = epoch_bar(config.optim.epochs, "baseline");
        let baseline = train_baseline(&data, &baseline_config(&config, goal), |p: &Progress| {
            bar.set_position(p.epoch as u64);
            bar.set_message(format!(
                "loss {:.4} val MSE {:.4}",
                p.train_loss, p.validation
            ));
        })
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
    use super::{ModelArgs, subset, task_recipe};
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
        let recipe = task_recipe(registry::entry(task).unwrap(), 6).unwrap();
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
        // The other recipes that fit every demonstration keep doing so.
        for task in ["limit-cycle", "lasa"] {
            let recipe = configured(task, &[]);
            assert_eq!(recipe.validation_fraction, 0.0, "{task}");
            assert_eq!(recipe.optim.keep, Keep::Last, "{task}");
        }
        assert_eq!(configured("lasa", &[]).optim.epochs, 30);
        // Another go-to task keeps the generic defaults.
        let generic = configured("obstacle-avoidance", &[]);
        assert_eq!(
            (generic.optim.batch_size, generic.validation_fraction),
            (256, 0.2)
        );
    }

    /// The ten limit-cycle training phases, in the order a dataset might hold them.
    fn phases() -> Vec<Vec<f64>> {
        [0.3, 1.0, 0.0, 0.6, 0.1, 0.9, 0.4, 0.7, 0.2, 0.8]
            .map(|c| vec![c])
            .to_vec()
    }

    fn chosen(episodes: Vec<Vec<f64>>, count: usize) -> Vec<f64> {
        subset(episodes, count, 0, |e| e.as_slice())
            .unwrap()
            .into_iter()
            .map(|c| c[0])
            .collect()
    }

    #[test]
    fn scalar_contexts_are_spread_evenly_ends_included_in_the_dataset_order() {
        assert_eq!(chosen(phases(), 2), [1.0, 0.0]);
        assert_eq!(chosen(phases(), 5), [1.0, 0.0, 0.6, 0.2, 0.8]);
        assert_eq!(chosen(phases(), 10), phases().concat());
        // Repeated phases count once: 2 of 20 episodes are still the two ends.
        let doubled = [phases(), phases()].concat();
        assert_eq!(chosen(doubled, 2), [1.0, 0.0]);
    }

    #[test]
    fn other_contexts_are_drawn_at_random_and_too_many_is_an_error() {
        let layouts: Vec<Vec<f64>> = (0..10).map(|i| vec![i as f64, 0.0]).collect();
        let drawn = subset(layouts.clone(), 4, 3, |e| e.as_slice()).unwrap();
        assert_eq!(drawn.len(), 4);
        assert_ne!(drawn, layouts[..4], "not the first four");
        assert_eq!(
            drawn,
            subset(layouts.clone(), 4, 3, |e| e.as_slice()).unwrap()
        );
        assert!(subset(layouts, 11, 3, |e| e.as_slice()).is_err());
    }
}
