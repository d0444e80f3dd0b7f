//! `ciflow lasa`: the LASA handwriting benchmark (library: [`ciflow_experiments::lasa`]),
//! a stable flow against the behaviour-cloning baseline on each shape, or with
//! `--ablation` what each choice of the flow's recipe buys.

use std::collections::HashSet;
use std::path::PathBuf;

use anyhow::{Context, bail};
use ciflow_envs::lasa;
use ciflow_evaluation::lasa::{GOAL, REFERENCE_SHAPES};
use ciflow_experiments::lasa::{self as benchmark, RunEpoch, TASK, ablation};

use ciflow_cli::progress;
use ciflow_train::RecipeOverrides;
use ciflow_train::trainer::check_config;

#[derive(clap::Args, Debug)]
// A negative setting (`--arrival -1`) reaches the check that explains it, instead of
// being taken for a flag.
#[command(allow_negative_numbers = true)]
pub struct LasaArgs {
    /// Shapes to run, comma-separated (default: all 30).
    #[arg(long, value_delimiter = ',')]
    pub shapes: Option<Vec<String>>,
    /// Output directory (lasa.md, lasa.csv, checkpoints/, plots/, lasa.png).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an earlier run's results in --out (lasa.md, lasa.csv, lasa.png,
    /// checkpoints/, plots/; with --ablation ablation.md, ablation.csv, checkpoints/;
    /// other files stay), which a run otherwise refuses.
    #[arg(long)]
    pub overwrite: bool,
    /// Skip the PNG plots (they need Python with matplotlib).
    #[arg(long)]
    pub no_plots: bool,
    /// Instead of the benchmark, measure what each of the default recipe's choices buys:
    /// the flow retrained with one setting changed at a time, on the shapes given
    /// (default: the six of ImitationFlow's comparison), into `<out>/ablation.md`.
    #[arg(long)]
    pub ablation: bool,
    #[command(flatten)]
    pub model: RecipeOverrides,
}

pub fn run(args: LasaArgs) -> anyhow::Result<()> {
    // `ciflow train`'s configuration for `ciflow/Lasa-v0`: the goal as context.
    let recipe = ciflow_envs::registry::entry(TASK)?.training_recipe(GOAL.len())?;
    let config = args.model.apply(recipe, None)?;
    check_config(&config).context("checking the training settings")?;
    let default = match args.ablation {
        true => REFERENCE_SHAPES.map(String::from).to_vec(),
        false => lasa::shape_names()?,
    };
    let names = benchmark::shape_names(args.shapes, default)?;
    // A shape run twice would be trained twice and reported in two identical rows.
    let mut seen = HashSet::new();
    if let Some(repeated) = names.iter().find(|name| !seen.insert(*name)) {
        bail!("--shapes names `{repeated}` twice");
    }
    let budget = match args.ablation {
        true => ablation::budget(names.len(), &config),
        false => benchmark::budget(names.len(), &config),
    };
    let bar = progress::bar(budget, "lasa", "epochs");
    let on_epoch = |e: &RunEpoch| {
        bar.set_position(e.done);
        bar.set_message(format!(
            "{} {}: epoch {}/{} validation {:.3}",
            e.shape,
            e.model.name(),
            e.progress.epoch,
            e.progress.epochs,
            e.progress.validation
        ));
    };
    let table = match args.ablation {
        true => ablation::run(&names, &config, &args.out, args.overwrite, on_epoch)?,
        false => benchmark::benchmark(&names, &config, &args.out, args.overwrite, on_epoch)?,
    };
    bar.finish_and_clear();
    if !args.ablation && !args.no_plots {
        benchmark::plot(&args.out).context("drawing the plots")?;
    }
    println!("{table}");
    println!("wrote {}", args.out.display());
    Ok(())
}
