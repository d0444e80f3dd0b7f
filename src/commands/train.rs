//! `ciflow train`: fit a stable conditioned INN policy to demonstrations by exact maximum
//! likelihood (and, with `--baseline`, the unconstrained behaviour-cloning MLP used as the
//! stability check's negative control).

use std::path::{Path, PathBuf};

use anyhow::Context;
use ciflow_engine::flow::{CouplingKind, Goal, LatentKind};
use ciflow_train::{
    BaselineTrainConfig, Contexts, Demonstrations, Episode, OptimConfig, Progress, TrainConfig,
    train_baseline, train_flow,
};
use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Deserialize;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum LatentArg {
    /// Fixed-point attractor.
    GoTo,
    /// Limit cycle in the first two latent dimensions.
    LimitCycle,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum CouplingArg {
    /// Affine coupling with tanh-bounded log-scale.
    Affine,
    /// Rational-quadratic spline coupling with identity tails.
    Spline,
}

#[derive(clap::Args, Debug)]
pub struct TrainArgs {
    /// Task name, recorded in the checkpoint (loading into another task fails).
    #[arg(long)]
    pub task: String,
    /// Demonstrations file.
    #[arg(long)]
    pub demos: PathBuf,
    /// Checkpoint directory to write (config.json + weights.safetensors).
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, value_enum, default_value = "go-to")]
    pub latent: LatentArg,
    #[arg(long, value_enum, default_value = "spline")]
    pub coupling: CouplingArg,
    /// Number of (mixing, coupling) blocks.
    #[arg(long, default_value_t = 6)]
    pub layers: usize,
    /// Hidden widths of each conditioner MLP, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "64,64")]
    pub hidden: Vec<usize>,
    /// Context indices holding the go-to target (one per state dimension), comma-separated.
    #[arg(long, value_delimiter = ',')]
    pub goal_context_indices: Option<Vec<usize>>,
    /// Guaranteed latent contraction rate (1/s).
    #[arg(long, default_value_t = 0.1)]
    pub min_rate: f64,
    /// Steps per modelled transition (k-step density).
    #[arg(long, default_value_t = 1)]
    pub horizon: usize,
    #[arg(long, default_value_t = 200)]
    pub epochs: usize,
    #[arg(long, default_value_t = 256)]
    pub batch_size: usize,
    #[arg(long, default_value_t = 2e-3)]
    pub learning_rate: f64,
    /// Early-stopping patience in epochs.
    #[arg(long, default_value_t = 30)]
    pub patience: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// libtorch threads.
    #[arg(long, default_value_t = 1)]
    pub threads: i32,
    /// Also train the behaviour-cloning baseline into `<out>/baseline`.
    #[arg(long)]
    pub baseline: bool,
}

/// One episode of the provisional demonstrations format.
#[derive(Deserialize)]
struct EpisodeFile {
    states: Vec<Vec<f64>>,
    #[serde(default)]
    contexts: Option<Vec<Vec<f64>>>,
    #[serde(default)]
    context: Option<Vec<f64>>,
}

#[derive(Deserialize)]
struct DemonstrationsFile {
    dt: f64,
    episodes: Vec<EpisodeFile>,
}

/// Reads demonstrations. Provisional format until the environments define theirs — JSON
/// `{"dt": s, "episodes": [{"states": [[..]..], "contexts": [[..]..] | "context": [..]}]}`;
/// this is the only function to change when the real format lands.
pub fn read_demonstrations(path: &Path) -> anyhow::Result<Demonstrations> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let file: DemonstrationsFile =
        serde_json::from_str(&text).with_context(|| format!("parsing demonstrations {}", path.display()))?;
    let episodes = file
        .episodes
        .into_iter()
        .enumerate()
        .map(|(i, e)| {
            let contexts = match (e.contexts, e.context) {
                (Some(per_step), None) => Contexts::PerStep(per_step),
                (None, Some(one)) => Contexts::PerEpisode(one),
                (None, None) => Contexts::PerEpisode(Vec::new()),
                (Some(_), Some(_)) => anyhow::bail!("episode {i} has both `contexts` and `context`"),
            };
            Ok(Episode { states: e.states, contexts })
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(Demonstrations { episodes, dt: file.dt })
}

fn progress_bar(epochs: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(epochs as u64);
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} epochs {msg} ({elapsed})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_prefix(what.to_owned());
    bar
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let data = read_demonstrations(&args.demos)?;
    let optim = OptimConfig {
        epochs: args.epochs,
        batch_size: args.batch_size,
        learning_rate: args.learning_rate,
        patience: args.patience,
        seed: args.seed,
        ..OptimConfig::default()
    };
    let latent = match args.latent {
        LatentArg::GoTo => LatentKind::GoTo,
        LatentArg::LimitCycle => LatentKind::LimitCycle,
    };
    let coupling = match args.coupling {
        CouplingArg::Affine => CouplingKind::Affine { scale_bound: 2.0 },
        CouplingArg::Spline => CouplingKind::Spline { bins: 8, tail_bound: 4.0 },
    };
    let config = TrainConfig {
        coupling,
        layers: args.layers,
        hidden: args.hidden.clone(),
        min_rate: args.min_rate,
        goal_context_indices: args.goal_context_indices.clone(),
        horizon: args.horizon,
        threads: args.threads,
        optim: optim.clone(),
        ..TrainConfig::new(&args.task, latent)
    };
    let bar = progress_bar(args.epochs, "flow");
    let trained = train_flow(&data, &config, |p: &Progress| {
        bar.set_position(p.epoch as u64);
        bar.set_message(format!("loss {:.3} val NLL/transition {:.3}", p.train_loss, p.validation));
    })
    .context("training the flow")?;
    bar.finish();
    trained.save(&args.out).with_context(|| format!("writing {}", args.out.display()))?;
    let best = trained.history.iter().map(|p| p.validation).fold(f64::INFINITY, f64::min);
    println!(
        "flow: best validation NLL per transition {best:.4} (epoch {}), checkpoint {}",
        trained.best_epoch,
        args.out.display()
    );

    if args.baseline {
        let goal = match &args.goal_context_indices {
            Some(indices) => Goal::ContextIndices { indices: indices.clone() },
            None => Goal::State { value: mean_final_state(&data) },
        };
        let bar = progress_bar(args.epochs, "baseline");
        let baseline = train_baseline(
            &data,
            &BaselineTrainConfig {
                task: args.task.clone(),
                hidden: args.hidden.clone(),
                goal,
                validation_fraction: config.validation_fraction,
                threads: args.threads,
                optim,
            },
            |p: &Progress| {
                bar.set_position(p.epoch as u64);
                bar.set_message(format!("loss {:.4} val MSE {:.4}", p.train_loss, p.validation));
            },
        )
        .context("training the baseline")?;
        bar.finish();
        let dir = args.out.join("baseline");
        baseline.save(&dir).with_context(|| format!("writing {}", dir.display()))?;
        println!("baseline: checkpoint {}", dir.display());
    }
    Ok(())
}

/// The demonstrations' mean final state: the go-to goal when the context does not hold it.
fn mean_final_state(data: &Demonstrations) -> Vec<f64> {
    let n = data.episodes.len() as f64;
    let d = data.episodes[0].states[0].len();
    let mut goal = vec![0.0; d];
    for e in &data.episodes {
        for (g, v) in goal.iter_mut().zip(e.states.last().expect("validated non-empty")) {
            *g += v / n;
        }
    }
    goal
}
