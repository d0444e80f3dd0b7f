//! Work that splits into independent pieces, spread over the engines reachable on Zenoh:
//! the episodes of a closed-loop evaluation (`ciflow evaluate --engines`) and the rollouts
//! of a stability check (`ciflow stability --engines`).
//!
//! The checkpoint reaches the engines the way a trainer's does: [`load_checkpoint`]
//! publishes it on the checkpoint channel under a name made from its content, and waits
//! until every engine lists it. The work then goes out one share per query, [`IN_FLIGHT`]
//! per engine at once so each engine's cores stay busy while a reply travels; whichever
//! engine is free takes the next share, so faster engines take more. Episode `i` depends
//! only on its seed `seed + i` and rollout `i` only on `i` and the seed, so the merged
//! results equal one in-process run. An engine that fails or disappears stops the work
//! with its name.

use std::collections::BTreeSet;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use ciflow_engine::flow::checkpoint::{CONFIG_FILE, WEIGHTS_FILE};
use ciflow_envs::registry::Kwargs;
use ciflow_evaluation::stability::{Ending, StabilityConfig};
use ciflow_evaluation::stability_check::Subject;
use ciflow_evaluation::{EpisodeBatch, EvaluationConfig};

use crate::client::Client;
use crate::error::BridgeError;
use crate::publisher::CheckpointPublisher;
use crate::retry::retry_within;
use crate::signing::CheckpointSigner;

/// Queries each engine has in flight at once.
pub const IN_FLIGHT: usize = 2;

/// Stability rollouts per query: a pouring rollout that never converges takes its
/// 20 000 steps, about half a second, so a share stays well inside an engine's budget.
pub const ROLLOUT_SHARE: usize = 4;

/// How long [`load_checkpoint`] waits for every engine to list the checkpoint.
pub const LOAD_TIMEOUT: Duration = Duration::from_secs(15);

/// How long [`resolve_engines`] keeps asking a named engine that no query reaches: one
/// started a moment ago has not declared itself yet, and a client that joined as a Zenoh
/// peer is linked to the engines only after the router's gossip.
pub const JOIN_GRACE: Duration = Duration::from_secs(3);

/// How often [`load_checkpoint`] publishes again while it waits: a publication sent
/// before Zenoh has routed the engines' subscriptions reaches nobody.
const REPUBLISH_INTERVAL: Duration = Duration::from_millis(500);

/// The engines `wanted` names, to run work of `task` (Gymnasium id or short name) on, or to
/// spread a vector environment over: every reachable engine that serves it, in name order,
/// for `["*"]` (at least one must), else the names given, each asked (for up to
/// [`JOIN_GRACE`] while no query reaches it) whether it is there and serves it.
pub fn resolve_engines(
    client: &Client,
    wanted: &[String],
    task: &str,
) -> Result<Vec<String>, BridgeError> {
    if wanted.iter().any(|w| w == "*") {
        if wanted.len() > 1 {
            return Err(BridgeError::InvalidArgument(format!(
                "`*` (every engine) and engine names together: {}",
                wanted.join(",")
            )));
        }
        let engines: Vec<String> = client
            .discover()?
            .into_iter()
            .filter(|engine| engine.serves(task))
            .map(|engine| engine.name)
            .collect();
        if engines.is_empty() {
            return Err(BridgeError::NoEngineServing { task: task.into() });
        }
        return Ok(engines);
    }
    if let Some(twice) = wanted
        .iter()
        .enumerate()
        .find_map(|(i, w)| wanted[..i].contains(w).then_some(w))
    {
        return Err(BridgeError::InvalidArgument(format!(
            "engine `{twice}` is named twice"
        )));
    }
    if wanted.is_empty() {
        return Err(BridgeError::InvalidArgument("no engine named".into()));
    }
    for engine in wanted {
        let info = retry_within(
            JOIN_GRACE,
            || client.engine_info(engine),
            |outcome| matches!(outcome, Err(BridgeError::NoEngine { .. })),
        )
        .map_err(|source| engine_error(engine, source))?;
        if !info.serves(task) {
            return Err(engine_error(
                engine,
                BridgeError::InvalidArgument(format!("it does not serve {task}")),
            ));
        }
    }
    Ok(wanted.to_vec())
}

/// Publishes the checkpoint `dir` for the task built with `kwargs` until every engine of
/// `engines` serves it, and returns the policy name it is served under: `eval-` and a
/// hash of the checkpoint's files and `kwargs`, so that evaluating it again reuses it.
pub fn load_checkpoint(
    client: &Client,
    engines: &[String],
    dir: &Path,
    kwargs: &Kwargs,
    signer: Option<CheckpointSigner>,
) -> Result<String, BridgeError> {
    let mut hasher = DefaultHasher::new();
    for file in [CONFIG_FILE, WEIGHTS_FILE] {
        let path = dir.join(file);
        std::fs::read(&path)
            .map_err(|source| BridgeError::ReadCheckpoint { path, source })?
            .hash(&mut hasher);
    }
    serde_json::to_string(kwargs)
        .map_err(|e| BridgeError::InvalidArgument(format!("construction arguments: {e}")))?
        .hash(&mut hasher);
    let name = format!("eval-{:016x}", hasher.finish());
    let publisher = CheckpointPublisher::new(client.zenoh_session(), &name)?
        .with_kwargs(kwargs.clone())
        .with_signer(signer);
    let start = Instant::now();
    let mut waiting: BTreeSet<&String> = engines.iter().collect();
    loop {
        publisher.publish(dir, 0, f64::NAN)?;
        let published = Instant::now();
        while published.elapsed() < REPUBLISH_INTERVAL {
            let mut loaded = Vec::new();
            for engine in &waiting {
                let info = client
                    .engine_info(engine)
                    .map_err(|source| engine_error(engine, source))?;
                if info.policies.iter().any(|p| p.name == name) {
                    loaded.push(*engine);
                }
            }
            waiting.retain(|e| !loaded.contains(e));
            if waiting.is_empty() {
                return Ok(name);
            }
            if start.elapsed() > LOAD_TIMEOUT {
                let missing: Vec<&str> = waiting.iter().map(|e| e.as_str()).collect();
                return Err(BridgeError::CheckpointNotLoaded {
                    engines: missing.join(", "),
                    seconds: LOAD_TIMEOUT.as_secs(),
                });
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

/// The episodes of the evaluation `config` of policy `policy` (served by every engine of
/// `engines`, see [`load_checkpoint`]), one query per episode; `progress` is called with
/// the number of episodes done. The batches come back in episode order.
pub fn evaluate(
    client: &Client,
    engines: &[String],
    policy: &str,
    config: &EvaluationConfig,
    progress: impl FnMut(usize),
) -> Result<Vec<EpisodeBatch>, BridgeError> {
    config
        .validate()
        .map_err(|e| BridgeError::InvalidArgument(crate::error::full_message(&e)))?;
    share_out(
        engines,
        config.episodes,
        |engine, episode| client.evaluate(engine, policy, config, episode..episode + 1),
        |batch| batch.results.len(),
        progress,
    )
}

/// The endings of the observation-space rollouts `0..config.starts` of the stability
/// check `config` of `subject` of policy `policy` (served by every engine of `engines`),
/// [`ROLLOUT_SHARE`] rollouts per query, in order; `progress` is called with the number
/// of rollouts done.
pub fn stability_rollouts(
    client: &Client,
    engines: &[String],
    policy: &str,
    subject: Subject,
    config: &StabilityConfig,
    progress: impl FnMut(usize),
) -> Result<Vec<Ending>, BridgeError> {
    let endings = share_out(
        engines,
        config.starts.div_ceil(ROLLOUT_SHARE),
        |engine, share| {
            let first = share * ROLLOUT_SHARE;
            let trials = first..(first + ROLLOUT_SHARE).min(config.starts);
            client.stability(engine, policy, subject, config, trials)
        },
        Vec::len,
        progress,
    )?;
    Ok(endings.into_iter().flatten().collect())
}

/// Runs tasks `0..tasks` on `engines`, [`IN_FLIGHT`] at a time per engine, whichever is
/// free taking the next task. `progress` is called on this thread with the units done so
/// far, a result counting `units(result)`. The results come back in task order; the first
/// failure stops every engine and is returned with its engine's name.
fn share_out<T: Send>(
    engines: &[String],
    tasks: usize,
    run: impl Fn(&str, usize) -> Result<T, BridgeError> + Sync,
    units: impl Fn(&T) -> usize + Sync,
    mut progress: impl FnMut(usize),
) -> Result<Vec<T>, BridgeError> {
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let results = Mutex::new(Vec::with_capacity(tasks));
    let first_error = Mutex::new(None);
    std::thread::scope(|scope| {
        let workers: Vec<_> = engines
            .iter()
            .flat_map(|e| std::iter::repeat_n(e, IN_FLIGHT))
            .map(|engine| {
                scope.spawn(|| {
                    while !failed.load(Ordering::Relaxed) {
                        let task = next.fetch_add(1, Ordering::Relaxed);
                        if task >= tasks {
                            break;
                        }
                        match run(engine, task) {
                            Ok(result) => {
                                done.fetch_add(units(&result), Ordering::Relaxed);
                                lock(&results).push((task, result));
                            }
                            Err(source) => {
                                failed.store(true, Ordering::Relaxed);
                                lock(&first_error).get_or_insert(engine_error(engine, source));
                            }
                        }
                    }
                })
            })
            .collect();
        let mut reported = 0;
        while workers.iter().any(|w| !w.is_finished()) {
            let now = done.load(Ordering::Relaxed);
            if now != reported {
                progress(now);
                reported = now;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        progress(done.load(Ordering::Relaxed));
    });
    if let Some(error) = first_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(error);
    }
    let mut results = results.into_inner().unwrap_or_else(|p| p.into_inner());
    results.sort_by_key(|(task, _)| *task);
    Ok(results.into_iter().map(|(_, result)| result).collect())
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|p| p.into_inner())
}

fn engine_error(engine: &str, source: BridgeError) -> BridgeError {
    BridgeError::Engine {
        engine: engine.to_owned(),
        source: Box::new(source),
    }
}
