//! `ciflow train --from-zenoh N`: demonstrations collected from recorders over Zenoh
//! (`ciflow/v2/episodes/<task>/*`, see bridge/PROTOCOL.md) instead of read from a dataset.

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use ciflow_bridge::episodes::collect;
use ciflow_envs::dataset::DatasetSpec;
use ciflow_envs::registry::TaskEntry;
use ciflow_train::dataset::{self, ForeignFields};
use ciflow_train::{Demonstrations, Screened, Screening};

use ciflow_cli::network::NetworkArgs;
use ciflow_cli::progress;

/// Where the demonstrations come from besides `--demos`.
#[derive(clap::Args, Debug)]
pub struct ZenohSource {
    /// Collect this many episodes that recorders (`python -m ciflow.record`) publish on
    /// `ciflow/v2/episodes/<task>/*`, instead of reading --demos; with --demos they are also
    /// written there as a dataset, so that the run can be repeated from files. Start the
    /// trainer before the recorders: earlier episodes are not replayed.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..), conflicts_with = "state")]
    pub from_zenoh: Option<u64>,
    /// With --from-zenoh: longest wait for the next episode, in seconds.
    #[arg(
        long,
        default_value_t = 300.0,
        value_name = "SECONDS",
        requires = "from_zenoh"
    )]
    pub episode_timeout: f64,
    /// Zenoh flags of --from-zenoh and --publish (default: a client of the engine on
    /// tcp/127.0.0.1:7447, through which recorders publish and engines listen).
    #[command(flatten)]
    pub network: NetworkArgs,
}

/// The demonstrations of `task`: read from `demos` (converted into `converted` first when
/// `foreign` names its fields), or collected from Zenoh (and then written to `demos` when
/// given); prints what the screening left out.
pub fn demonstrations(
    task: &TaskEntry,
    demos: Option<&Path>,
    (foreign, converted): (&ForeignFields, &Path),
    source: &ZenohSource,
    screening: Screening,
) -> anyhow::Result<(DatasetSpec, Demonstrations)> {
    let report = |source: &str, screened: Screened| println!("{source}: {screened}");
    let Some(count) = source.from_zenoh else {
        let demos = demos.context("give the dataset with --demos, or --from-zenoh <N>")?;
        let (spec, data, screened) = match foreign.state {
            None => dataset::read(demos, task, screening),
            Some(_) => dataset::convert_foreign(demos, converted, foreign)
                .and_then(|dir| dataset::read_foreign(&dir, screening)),
        }
        .with_context(|| format!("reading the dataset {}", demos.display()))?;
        report(&demos.display().to_string(), screened);
        return Ok((spec, data));
    };
    let timeout = Duration::try_from_secs_f64(source.episode_timeout)
        .ok()
        .filter(|t| !t.is_zero())
        .with_context(|| {
            format!(
                "--episode-timeout {:?}: give a positive number of seconds up to {:e}",
                source.episode_timeout,
                Duration::MAX.as_secs_f64()
            )
        })?;
    if let Some(dir) = demos {
        anyhow::ensure!(
            !dir.exists(),
            "{} already exists; --demos with --from-zenoh writes a new dataset",
            dir.display()
        );
    }
    let network = source.network.options()?;
    let bar = progress::bar(count, task.name, "episodes");
    let (spec, episodes) = collect(
        &network,
        task.name,
        count as usize,
        timeout,
        |key| {
            // Scripts and tests start the recorders once this line is out.
            println!("waiting for {count} episodes on {key}");
            bar.set_message("waiting");
        },
        |message| {
            bar.inc(1);
            bar.set_message(format!("from {}", message.recorder));
        },
    )
    .with_context(|| format!("collecting {count} episodes of `{}` from Zenoh", task.name))?;
    bar.finish();
    if let Some(dir) = demos {
        ciflow_envs::dataset::write(dir, &spec, &episodes, false)
            .with_context(|| format!("writing the collected episodes to {}", dir.display()))?;
        println!(
            "wrote {} ({}): {count} episodes",
            dir.display(),
            spec.dataset_id
        );
    }
    let source = "the episodes collected from Zenoh";
    dataset::recorded_on(&spec, task, source)?;
    let (data, screened) = dataset::demonstrations(&spec, episodes, source, screening)?;
    report(source, screened);
    Ok((spec, data))
}
