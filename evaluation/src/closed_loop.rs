//! Closed-loop evaluation of a checkpoint in its task's environment: the issue's
//! experiment numbers (success, goal-reached, collision and spill rates, final distances,
//! episode lengths), under optional disturbances, plus per-step traces for figures.
//!
//! Episode `i` is reset with seed `seed + i`, so its context and start are the task's own
//! random draws and the same for every checkpoint and every disturbance mode. Every
//! control step the [`Actor`] chooses `q̈_des` from the observation `[q, q̇, c]` — or, as
//! the reference the policies imitate, the task's expert does ([`Acting::Expert`]), under
//! the same disturbances and measures.
//!
//! **Outcome of an episode** (from the task's `info`, see each task's module docs):
//! *success* when the last step reports `is_success = 1` (obstacle avoidance terminates on
//! reaching the target; pouring keeps `is_success = 1` while it pours; the limit cycle
//! reports it while on the outline); *collision* / *spill* when any step reports
//! `collision = 1` / `spill = 1`; the *final distance* is the last value of the task's
//! distance key ([`DISTANCE_KEYS`]). The last step alone cannot tell a cyclic motion that
//! stays on its cycle from one that stopped on it, so every episode also reports how it
//! moves over its second half ([`SecondHalf`]): the mean of the distance key and the
//! mean speed `‖q̇‖`.
//!
//! Disturbances ([`Disturbance`]) are the pushes of [`push`] and the mid-motion context
//! changes of [`Disturbance::Context`].
//!
//! Episodes that replay the model's own demonstrations (the recording's seeds) are also
//! counted apart, fitted and held out ([`EvaluationReport::divide_by`], [`SplitRates`]).

use std::collections::BTreeMap;
use std::ops::Range;

use serde::{Deserialize, Serialize};

use ciflow_engine::flow::checkpoint::split::{SplitRole, TrainingSplit};
use ciflow_envs::actor::{Actor, Model};
use ciflow_envs::env::{Env, EnvSpec, Info, ResetOptions, SUCCESS_INFO};
use ciflow_envs::registry;

use crate::push::{self, PushConfig, PushOutcome, PushSummary};
use crate::summary::Summary;
use crate::trace::Trace;
use crate::{EvaluationError, EvaluationResult};

/// `info` keys holding the distance to the task's goal, in order of preference: obstacle
/// avoidance and LASA, pouring, limit cycle.
pub const DISTANCE_KEYS: [&str; 3] = ["distance_to_target", "pour_distance", "outline_error"];
/// A context change in the middle of the motion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ContextSwitch {
    /// Simulated time of the change, s.
    pub time: f64,
    /// Change only the last `tail` context entries (obstacle avoidance: `2`, the target),
    /// keeping the others; `None` changes the whole context (pouring: the pot's pose).
    pub tail: Option<usize>,
}

/// What happens to an episode besides the policy acting.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum Disturbance {
    None,
    /// A push sized to displace the tracked point by a minimum distance ([`push`]).
    Push(PushConfig),
    /// The context moves to a new valid draw of the task's distribution, which then holds.
    Context(ContextSwitch),
}

impl std::fmt::Display for Disturbance {
    /// One phrase for the printed summary, e.g. "pushed on link 1 at 1 s for 0.2 s".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => write!(f, "undisturbed"),
            Self::Push(push) => write!(
                f,
                "pushed on link {} at {} s for {} s (to a displacement >= {} m)",
                push.link, push.start, push.duration, push.displacement
            ),
            Self::Context(ContextSwitch { time, tail }) => match tail {
                Some(tail) => write!(f, "the last {tail} context entries changed at {time} s"),
                None => write!(f, "the context changed at {time} s"),
            },
        }
    }
}

/// Who chooses the actions of the evaluated episodes.
#[derive(Clone, Copy, Debug)]
pub enum Acting<'a> {
    /// A trained checkpoint, through an [`Actor`] with [`EvaluationConfig::velocity_gain`].
    Model(&'a Model),
    /// The task's expert ([`Env::expert_action`]), which made the demonstrations: what it
    /// reaches under a disturbance is what imitating it can be expected to reach.
    Expert,
}

/// [`Acting`] with its buffers.
enum Driver {
    Actor(Box<Actor>),
    Expert,
}

impl Driver {
    fn reset(&mut self) {
        if let Self::Actor(actor) = self {
            actor.reset();
        }
    }

    fn act(
        &mut self,
        env: &dyn Env,
        observation: &[f64],
        action: &mut [f64],
    ) -> EvaluationResult<()> {
        match self {
            Self::Actor(actor) => actor.act(observation, action)?,
            Self::Expert => action.copy_from_slice(&env.expert_action()?),
        }
        Ok(())
    }
}

/// Settings of [`evaluate`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluationConfig {
    pub episodes: usize,
    /// Episode `i` is reset with `seed + i`.
    pub seed: u64,
    /// `K_v` of the [`Actor`], 1/s (unused by the expert).
    pub velocity_gain: f64,
    /// Reset options for every episode (e.g. limit cycle's `context_set`).
    pub reset_extra: BTreeMap<String, f64>,
    pub disturbance: Disturbance,
    /// How many episodes' traces to keep (the first ones).
    pub trajectories: usize,
}

/// What one episode did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    pub seed: u64,
    /// The position `q` at reset.
    #[serde(default)]
    pub start: Vec<f64>,
    /// The context at reset.
    pub context: Vec<f64>,
    pub success: bool,
    /// `Some` for tasks that report collisions (obstacle avoidance).
    pub collision: Option<bool>,
    /// `Some` for tasks that report spills (pouring).
    pub spill: Option<bool>,
    /// Last value of the task's distance key, if it has one.
    pub final_distance: Option<f64>,
    /// How the episode moved over its second half (absent from reports written before
    /// it was measured).
    #[serde(default)]
    pub second_half: Option<SecondHalf>,
    pub steps: usize,
    pub terminated: bool,
    /// The context after a [`Disturbance::Context`] change.
    pub switched_context: Option<Vec<f64>>,
    pub push: Option<PushOutcome>,
}

/// Means over the second half of an episode's states (from state `⌊n/2⌋` of the `n`
/// recorded, the reset's included).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SecondHalf {
    /// Mean of the task's distance key, if it has one (the limit cycle: the mean distance
    /// to the outline, m).
    pub distance: Option<f64>,
    /// Mean speed `‖q̇‖` (m/s or rad/s): about the expert's along a cycle, zero for a
    /// motion that stopped.
    pub speed: f64,
}

impl SecondHalf {
    /// From the trace of an episode and its distance key's value at each recorded state
    /// (empty when the task has none).
    fn of(trace: &Trace, distances: &[f64]) -> Self {
        let start = trace.qd.len() / 2;
        let half = (trace.qd.len() - start) as f64;
        let speed = trace.qd[start..]
            .iter()
            .map(|qd| qd.iter().map(|v| v * v).sum::<f64>().sqrt())
            .sum::<f64>()
            / half;
        let distance = (distances.len() == trace.qd.len())
            .then(|| distances[start..].iter().sum::<f64>() / half);
        Self { distance, speed }
    }
}

/// An example episode for figures: the disturbed run and, for pushes, its undisturbed
/// reference (same seed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Example {
    pub seed: u64,
    pub trace: Trace,
    pub reference: Option<Trace>,
}

/// Outcome of [`evaluate`]; written as JSON by `ciflow evaluate`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvaluationReport {
    pub env_id: String,
    pub task: String,
    /// `flow`, `baseline` or `expert`.
    pub model: String,
    pub disturbance: Disturbance,
    pub seed: u64,
    pub episodes: usize,
    pub success_rate: f64,
    pub collision_rate: Option<f64>,
    pub spill_rate: Option<f64>,
    /// Which `info` key [`final_distance`](Self::final_distance) summarises.
    pub distance_key: Option<String>,
    pub final_distance: Option<Summary>,
    /// Over the episodes, the mean distance ([`SecondHalf::distance`]) and the mean speed
    /// ([`SecondHalf::speed`]) of each episode's second half.
    pub second_half_distance: Option<Summary>,
    pub second_half_speed: Option<Summary>,
    pub episode_steps: Option<Summary>,
    pub push: Option<PushSummary>,
    /// The rates of the episodes that replay the model's demonstrations, fitted and held
    /// out apart ([`EvaluationReport::divide_by`]); `None` when none do.
    pub training_split: Option<SplitRates>,
    pub results: Vec<EpisodeResult>,
    /// Traces of the first [`EvaluationConfig::trajectories`] episodes.
    pub trajectories: Vec<Trace>,
    /// The first episode in full, for the disturbance figures.
    pub example: Option<Example>,
}

impl EvaluationReport {
    /// Divides the rates by the episodes' part in the model's training `split`, when some
    /// episodes replay its demonstrations.
    pub fn divide_by(&mut self, split: &TrainingSplit) {
        let rates = SplitRates::of(&self.results, split);
        self.training_split = rates.touches_data().then_some(rates);
    }
}

impl std::fmt::Display for EvaluationReport {
    /// The summary `ciflow evaluate` prints: rates, final distance, episode length and, for
    /// pushes, displacement and recovery.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let percent = |r: f64| format!("{:.1}%", 100.0 * r);
        write!(
            f,
            "{} ({}) on {}, {}: success {}",
            self.task,
            self.model,
            self.env_id,
            self.disturbance,
            percent(self.success_rate)
        )?;
        if let Some(r) = self.collision_rate {
            write!(f, ", collision {}", percent(r))?;
        }
        if let Some(r) = self.spill_rate {
            write!(f, ", spill {}", percent(r))?;
        }
        if let (Some(key), Some(d)) = (&self.distance_key, &self.final_distance) {
            write!(f, ", final {key} {:.4} ± {:.4}", d.mean, d.std)?;
        }
        if let Some(s) = &self.episode_steps {
            write!(f, ", {:.0} ± {:.0} steps", s.mean, s.std)?;
        }
        writeln!(f, " ({} episodes)", self.episodes)?;
        if let Some(speed) = &self.second_half_speed {
            write!(
                f,
                "second half of the episodes: speed {:.3} (min {:.3})",
                speed.mean, speed.min
            )?;
            if let (Some(key), Some(d)) = (&self.distance_key, &self.second_half_distance) {
                write!(f, ", {key} {:.4} (max {:.4})", d.mean, d.max)?;
            }
            writeln!(f)?;
        }
        if let Some(split) = &self.training_split {
            write!(f, "{split}")?;
        }
        if let Some(push) = &self.push {
            writeln!(
                f,
                "push: displacement {:.4} ± {:.4} (min {:.4}; ≥ {} in {}), recovered within {} \
                 of the unpushed path in {} ({} within {} s; mean {:.2} s)",
                push.displacement.mean,
                push.displacement.std,
                push.displacement.min,
                push.required_displacement,
                percent(push.displaced_fraction),
                push.recovery_tolerance,
                percent(push.recovered_fraction),
                percent(push.recovered_within_deadline_fraction),
                push.recovery_deadline,
                push.recovery_time.as_ref().map_or(f64::NAN, |t| t.mean),
            )?;
        }
        Ok(())
    }
}

/// A scheduled disturbance of one run.
#[derive(Clone, Debug)]
enum Schedule {
    Free,
    Push(ciflow_engine::sim::Perturbation),
    Switch {
        time: f64,
        candidates: Vec<Vec<f64>>,
    },
}

/// One closed-loop run.
#[derive(Clone, Debug)]
struct Run {
    trace: Trace,
    /// The task's distance key ([`DISTANCE_KEYS`]), the first that a step reports, and its
    /// value at each state of `trace` that reports it.
    distance_key: Option<&'static str>,
    distances: Vec<f64>,
    last_info: Info,
    collision: bool,
    spill: bool,
    terminated: bool,
    switched_context: Option<Vec<f64>>,
}

/// Runs `driver` from `reset(seed)` until the episode ends, applying `schedule`.
fn run_episode(
    env: &mut dyn Env,
    driver: &mut Driver,
    state_dim: usize,
    seed: u64,
    options: &ResetOptions,
    schedule: &Schedule,
) -> EvaluationResult<Run> {
    let (mut observation, mut info) = env.reset(Some(seed), options)?;
    driver.reset();
    if let Schedule::Push(perturbation) = schedule {
        env.perturb(perturbation.clone())?;
    }
    let mut trace = Trace::default();
    trace.record(&observation, state_dim, &info);
    let (mut distance_key, mut distances) = (None, Vec::new());
    let mut record_distance = |info: &Info| {
        distance_key =
            distance_key.or_else(|| DISTANCE_KEYS.into_iter().find(|k| info.contains_key(k)));
        if let Some(value) = distance_key.and_then(|k| info.get(k)) {
            distances.push(*value);
        }
    };
    record_distance(&info);
    let flag = |info: &Info, key: &str| info.get(key).is_some_and(|&v| v == 1.0);
    let (mut collision, mut spill) = (flag(&info, "collision"), flag(&info, "spill"));
    let mut switched_context = None;
    let mut action = vec![0.0; state_dim];
    let terminated = loop {
        if let Schedule::Switch { time, candidates } = schedule
            && switched_context.is_none()
            && trace.time.last().is_some_and(|t| *t >= time - 1e-9)
        {
            let chosen = candidates
                .iter()
                .find(|c| env.set_context(c).is_ok())
                .ok_or(EvaluationError::NoValidContext {
                    seed,
                    tries: candidates.len(),
                })?;
            switched_context = Some(chosen.clone());
            let context_start = observation.len() - chosen.len();
            observation[context_start..].copy_from_slice(chosen);
        }
        driver.act(env, &observation, &mut action)?;
        let step = env.step(&action)?;
        trace.command.push(action.clone());
        observation = step.observation;
        info = step.info;
        trace.record(&observation, state_dim, &info);
        record_distance(&info);
        collision |= flag(&info, "collision");
        spill |= flag(&info, "spill");
        if step.terminated || step.truncated {
            break step.terminated;
        }
    };
    Ok(Run {
        trace,
        distance_key,
        distances,
        last_info: info,
        collision,
        spill,
        terminated,
        switched_context,
    })
}

/// Contexts for a mid-motion change: fresh draws of the task's distribution (resets with
/// seeds derived from `seed`), of which the last `tail` entries replace those of
/// `current`. The first one the environment accepts is used.
fn switch_candidates(
    env: &mut dyn Env,
    options: &ResetOptions,
    seed: u64,
    current: &[f64],
    tail: Option<usize>,
) -> EvaluationResult<Vec<Vec<f64>>> {
    const DRAWS: u64 = 16;
    let m = current.len();
    let keep = match tail {
        Some(t) if t == 0 || t > m => {
            return Err(EvaluationError::InvalidConfig(format!(
                "the changed tail must have 1 to {m} context entries, got {t}"
            )));
        }
        Some(t) => m - t,
        None => 0,
    };
    (0..DRAWS)
        .map(|k| {
            let draw_seed = seed ^ (0x9e37_79b9_7f4a_7c15_u64.wrapping_mul(k + 1));
            let (observation, _) = env.reset(Some(draw_seed), options)?;
            let drawn = &observation[observation.len() - m..];
            Ok([&current[..keep], &drawn[keep..]].concat())
        })
        .collect()
}

fn model_name(acting: Acting) -> &'static str {
    match acting {
        Acting::Model(Model::Flow(_)) => "flow",
        Acting::Model(Model::Baseline(_)) => "baseline",
        Acting::Expert => "expert",
    }
}

fn rate(flags: impl Iterator<Item = Option<bool>>) -> Option<f64> {
    let flags: Vec<bool> = flags.collect::<Option<_>>()?;
    (!flags.is_empty()).then(|| flags.iter().filter(|f| **f).count() as f64 / flags.len() as f64)
}

impl EvaluationConfig {
    /// Refuses settings no episode can run with: no episodes, an invalid push, a context
    /// change at a time that is not a time.
    pub fn validate(&self) -> EvaluationResult<()> {
        if self.episodes == 0 {
            return Err(EvaluationError::InvalidConfig(
                "at least one episode is needed".into(),
            ));
        }
        match &self.disturbance {
            Disturbance::Push(push) => push.validate()?,
            Disturbance::Context(switch) if !(switch.time.is_finite() && switch.time >= 0.0) => {
                return Err(EvaluationError::InvalidConfig(format!(
                    "the context change's time must be finite and >= 0, got {}",
                    switch.time
                )));
            }
            _ => {}
        }
        Ok(())
    }

    /// Refuses a disturbance that starts after the episodes of `spec` end: it would never
    /// happen, and the report would pass unperturbed episodes off as perturbed ones.
    pub fn fits_episode(&self, spec: &EnvSpec) -> EvaluationResult<()> {
        let end = f64::from(spec.max_episode_steps) * spec.control_dt;
        let (what, start) = match &self.disturbance {
            Disturbance::None => return Ok(()),
            Disturbance::Push(push) => ("push", push.start),
            Disturbance::Context(switch) => ("context change", switch.time),
        };
        if start < end {
            Ok(())
        } else {
            Err(EvaluationError::InvalidConfig(format!(
                "the {what} at {start} s would come after the episode's end ({end} s = {} \
                 steps of {} s in {})",
                spec.max_episode_steps, spec.control_dt, spec.id
            )))
        }
    }
}

/// Some consecutive episodes of an evaluation, as [`run_episodes`] returns them and
/// [`summarize`] merges them: wherever they ran, episode `i` depends only on its seed
/// `seed + i`, so batches run apart (on other threads, processes or machines) add up to
/// the report of one run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeBatch {
    /// Index of the first episode.
    pub first: usize,
    pub results: Vec<EpisodeResult>,
    /// Traces of the batch's episodes among the first [`EvaluationConfig::trajectories`].
    pub trajectories: Vec<Trace>,
    /// Episode 0 in full, if the batch holds it.
    pub example: Option<Example>,
    /// The first distance key an episode of the batch reported.
    pub distance_key: Option<String>,
}

impl EpisodeBatch {
    /// Appends the batch that follows this one.
    pub fn append(&mut self, next: EpisodeBatch) {
        debug_assert_eq!(next.first, self.first + self.results.len());
        self.results.extend(next.results);
        self.trajectories.extend(next.trajectories);
        self.example = self.example.take().or(next.example);
        self.distance_key = self.distance_key.take().or(next.distance_key);
    }
}

/// Runs `config.episodes` closed-loop episodes of `acting` in `env`; `progress` is called
/// after each episode with the number done.
pub fn evaluate(
    env: &mut dyn Env,
    acting: Acting,
    config: &EvaluationConfig,
    progress: impl FnMut(usize),
) -> EvaluationResult<EvaluationReport> {
    config.validate()?;
    let batch = run_episodes(env, acting, config, 0..config.episodes, progress)?;
    summarize(env.spec(), acting, config, vec![batch])
}

/// Runs the episodes `episodes` (indices below `config.episodes`) of the evaluation
/// `config`; `progress` is called after each episode with the number done.
pub fn run_episodes(
    env: &mut dyn Env,
    acting: Acting,
    config: &EvaluationConfig,
    episodes: Range<usize>,
    mut progress: impl FnMut(usize),
) -> EvaluationResult<EpisodeBatch> {
    config.validate()?;
    config.fits_episode(env.spec())?;
    if episodes.end > config.episodes {
        return Err(EvaluationError::InvalidConfig(format!(
            "episodes {}..{} of an evaluation of {}",
            episodes.start, episodes.end, config.episodes
        )));
    }
    let spec = env.spec().clone();
    let mut driver = match acting {
        Acting::Model(model) => {
            Driver::Actor(Box::new(Actor::new(model, &spec, config.velocity_gain)?))
        }
        Acting::Expert => Driver::Expert,
    };
    let d = spec.action_space.dim();
    let options = ResetOptions {
        extra: config.reset_extra.clone(),
        ..ResetOptions::default()
    };
    let mut batch = EpisodeBatch {
        first: episodes.start,
        results: Vec::with_capacity(episodes.len()),
        trajectories: Vec::new(),
        example: None,
        distance_key: None,
    };
    for (done, i) in episodes.enumerate() {
        let seed = config.seed.wrapping_add(i as u64);
        let (run, reference, push) = match &config.disturbance {
            Disturbance::None => (
                run_episode(env, &mut driver, d, seed, &options, &Schedule::Free)?,
                None,
                None,
            ),
            Disturbance::Context(switch) => {
                let (observation, _) = env.reset(Some(seed), &options)?;
                let current = &observation[2 * d..];
                let candidates = switch_candidates(env, &options, seed, current, switch.tail)?;
                let schedule = Schedule::Switch {
                    time: switch.time,
                    candidates,
                };
                let run = run_episode(env, &mut driver, d, seed, &options, &schedule)?;
                (run, None, None)
            }
            Disturbance::Push(push) => {
                let reference = run_episode(env, &mut driver, d, seed, &options, &Schedule::Free)?;
                let (run, outcome) = push::sized_push(push, seed, &reference.trace, |p| {
                    run_episode(env, &mut driver, d, seed, &options, &Schedule::Push(p))
                        .map(|run| (run.trace.clone(), run))
                })?;
                (run, Some(reference.trace), Some(outcome))
            }
        };
        let key = run.distance_key;
        batch.distance_key = batch.distance_key.or(key.map(str::to_owned));
        let has = |key: &str| run.last_info.contains_key(key);
        batch.results.push(EpisodeResult {
            seed,
            start: run.trace.q[0].clone(),
            context: run.trace.context[0].clone(),
            success: run.last_info.get(SUCCESS_INFO).is_some_and(|&s| s == 1.0),
            collision: has("collision").then_some(run.collision),
            spill: has("spill").then_some(run.spill),
            final_distance: key.and_then(|k| run.last_info.get(k).copied()),
            second_half: Some(SecondHalf::of(&run.trace, &run.distances)),
            steps: run.trace.command.len(),
            terminated: run.terminated,
            switched_context: run.switched_context.clone(),
            push,
        });
        if i < config.trajectories {
            batch.trajectories.push(run.trace.clone());
        }
        if i == 0 {
            batch.example = Some(Example {
                seed,
                trace: run.trace,
                reference,
            });
        }
        progress(done + 1);
    }
    Ok(batch)
}

/// The report of the evaluation `config` of `acting` in the task of `spec`, from batches
/// that together hold its episodes `0..config.episodes` once each (in any order).
pub fn summarize(
    spec: &EnvSpec,
    acting: Acting,
    config: &EvaluationConfig,
    mut batches: Vec<EpisodeBatch>,
) -> EvaluationResult<EvaluationReport> {
    batches.sort_by_key(|b| b.first);
    let mut next = 0;
    for batch in &batches {
        if batch.first != next {
            return Err(EvaluationError::InvalidConfig(format!(
                "the batches skip or repeat episodes at episode {next} (a batch starts at {})",
                batch.first
            )));
        }
        next += batch.results.len();
    }
    if next != config.episodes {
        return Err(EvaluationError::InvalidConfig(format!(
            "the batches hold {next} episodes of {}",
            config.episodes
        )));
    }
    let task = match acting {
        Acting::Model(model) => model.task().to_owned(),
        Acting::Expert => {
            registry::entry(&spec.id).map_or_else(|_| spec.id.clone(), |e| e.name.to_owned())
        }
    };
    let distance_key = batches.iter().find_map(|b| b.distance_key.clone());
    let example = batches.iter_mut().find_map(|b| b.example.take());
    let mut results = Vec::with_capacity(config.episodes);
    let mut trajectories = Vec::new();
    for batch in batches {
        results.extend(batch.results);
        trajectories.extend(batch.trajectories);
    }
    let n = results.len() as f64;
    let distances: Vec<f64> = results.iter().filter_map(|r| r.final_distance).collect();
    let second_halves: Vec<&SecondHalf> = results
        .iter()
        .filter_map(|r| r.second_half.as_ref())
        .collect();
    let second_half_distances: Vec<f64> = second_halves.iter().filter_map(|h| h.distance).collect();
    let second_half_speeds: Vec<f64> = second_halves.iter().map(|h| h.speed).collect();
    let steps: Vec<f64> = results.iter().map(|r| r.steps as f64).collect();
    let push = match &config.disturbance {
        Disturbance::Push(push) => {
            let pushes: Vec<(&PushOutcome, bool)> = results
                .iter()
                .filter_map(|r| r.push.as_ref().map(|p| (p, r.success)))
                .collect();
            PushSummary::of(push, &pushes)
        }
        _ => None,
    };
    Ok(EvaluationReport {
        env_id: spec.id.clone(),
        task,
        model: model_name(acting).into(),
        disturbance: config.disturbance.clone(),
        seed: config.seed,
        episodes: results.len(),
        success_rate: results.iter().filter(|r| r.success).count() as f64 / n,
        collision_rate: rate(results.iter().map(|r| r.collision)),
        spill_rate: rate(results.iter().map(|r| r.spill)),
        distance_key,
        final_distance: Summary::of(&distances),
        second_half_distance: Summary::of(&second_half_distances),
        second_half_speed: Summary::of(&second_half_speeds),
        episode_steps: Summary::of(&steps),
        push,
        training_split: None,
        results,
        trajectories,
        example,
    })
}

// The rates divided by what the model saw in training: the episodes that replay
// demonstrations it fitted, those that replay the demonstrations its training held out
// for validation, and the rest ([`TrainingSplit::role`] decides, from each episode's
// seed, start and context). Evaluating a model on its own demonstrations' seeds asks
// whether it fits its data; the answer means that only for the fitted part; the held-out
// part is a generalisation figure like any other unseen episode.

/// The outcome rates of some episodes.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Rates {
    pub episodes: usize,
    pub success_rate: f64,
    pub collision_rate: Option<f64>,
    pub spill_rate: Option<f64>,
    pub final_distance: Option<Summary>,
}

impl Rates {
    /// The rates of `results`; `None` when there are none.
    pub fn of(results: &[&EpisodeResult]) -> Option<Self> {
        if results.is_empty() {
            return None;
        }
        let distances: Vec<f64> = results.iter().filter_map(|r| r.final_distance).collect();
        Some(Self {
            episodes: results.len(),
            success_rate: results.iter().filter(|r| r.success).count() as f64
                / results.len() as f64,
            collision_rate: rate(results.iter().map(|r| r.collision)),
            spill_rate: rate(results.iter().map(|r| r.spill)),
            final_distance: Summary::of(&distances),
        })
    }
}

/// An evaluation's episodes by their part in the model's training.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SplitRates {
    /// Episodes that replay demonstrations the model was fitted to.
    pub fitted: Option<Rates>,
    /// Episodes that replay demonstrations held out for validation (never fitted).
    pub held_out: Option<Rates>,
    /// Episodes that replay no demonstration.
    pub not_in_data: Option<Rates>,
}

impl SplitRates {
    pub fn of(results: &[EpisodeResult], split: &TrainingSplit) -> Self {
        let part = |role: SplitRole| {
            let members: Vec<&EpisodeResult> = results
                .iter()
                .filter(|r| split.role(r.seed, &r.start, &r.context) == role)
                .collect();
            Rates::of(&members)
        };
        Self {
            fitted: part(SplitRole::Fitted),
            held_out: part(SplitRole::HeldOut),
            not_in_data: part(SplitRole::NotInData),
        }
    }

    /// Whether any episode replays a demonstration (else the division says nothing).
    pub fn touches_data(&self) -> bool {
        self.fitted.is_some() || self.held_out.is_some()
    }
}

impl std::fmt::Display for SplitRates {
    /// One line per part, e.g. "fitted in training: success 99.9%, collision 0.1% (800)".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts = [
            ("fitted in training", &self.fitted),
            ("held out of training", &self.held_out),
            ("not among the demonstrations", &self.not_in_data),
        ];
        for (name, rates) in parts {
            let Some(rates) = rates else { continue };
            write!(f, "{name}: success {:.1}%", 100.0 * rates.success_rate)?;
            if let Some(r) = rates.collision_rate {
                write!(f, ", collision {:.1}%", 100.0 * r)?;
            }
            if let Some(r) = rates.spill_rate {
                write!(f, ", spill {:.1}%", 100.0 * r)?;
            }
            writeln!(f, " ({} episodes)", rates.episodes)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trace of unit-circle positions at `angles`, moving at `speed` tangentially.
    fn circle(angles: &[f64], speed: f64) -> Trace {
        let mut trace = Trace::default();
        for &a in angles {
            trace.q.push(vec![a.cos(), a.sin()]);
            trace.qd.push(vec![-speed * a.sin(), speed * a.cos()]);
        }
        trace
    }

    /// A motion that stops on its cycle ends as close to it as one that keeps circulating:
    /// the last distance cannot tell them apart, the second half's speed does.
    #[test]
    fn the_second_half_tells_a_stopped_cycle_from_a_circulating_one() {
        let angles: Vec<f64> = (0..10).map(|k| 0.1 * k as f64).collect();
        let on_the_cycle = vec![0.0; angles.len()];
        let circulating = SecondHalf::of(&circle(&angles, 0.8), &on_the_cycle);
        let mut stopped = circle(&angles, 0.8);
        stopped.qd[7..]
            .iter_mut()
            .for_each(|qd| *qd = vec![0.0, 0.0]);
        let stopped = SecondHalf::of(&stopped, &on_the_cycle);
        assert_eq!(circulating.distance, Some(0.0));
        assert_eq!(stopped.distance, Some(0.0));
        assert!((circulating.speed - 0.8).abs() < 1e-12);
        // States 5..10: two of five still moving.
        assert!(
            (stopped.speed - 0.8 * 2.0 / 5.0).abs() < 1e-12,
            "{stopped:?}"
        );
        // The distance's mean covers the same states; without one per state there is none.
        let distances: Vec<f64> = (0..10).map(f64::from).collect();
        assert_eq!(
            SecondHalf::of(&circle(&angles, 0.8), &distances).distance,
            Some(7.0)
        );
        assert_eq!(SecondHalf::of(&circle(&angles, 0.8), &[]).distance, None);
    }
}
