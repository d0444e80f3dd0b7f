//! Demonstrations from a `ciflow demos` dataset (Minari's layout, [`ciflow_envs::dataset`]).
//!
//! A dataset episode observes `[q, q̇, c]` at every control step; the policy models the
//! positions `y = q` under the per-step contexts `c`, sampled every `control_dt`. What the
//! trainer leaves out by default, and why:
//!
//! - episodes whose last step is not a success (spilled, collided, never arrived): they
//!   show what not to do;
//! - transitions an external force moved, and those within a settling window after each:
//!   they show the push, not the expert. A second-order expert still carries the push's
//!   velocity for a while after the force stops, so the window is the task's to choose.
//!
//! [`Screening`] keeps either on request; [`Screened`] reports the counts.
//!
//! A Minari or LeRobot dataset made by another tool is converted first
//! ([`convert_foreign`]), with [`ForeignFields`] naming which of its fields are the state
//! and the context.

use std::fmt;
use std::path::{Path, PathBuf};

use ciflow_envs::dataset::{self, DatasetSpec};
use ciflow_envs::registry::TaskEntry;

use crate::data::{Contexts, Demonstrations, Episode};
use crate::error::{TrainError, TrainResult};

/// What of a dataset the trainer leaves out by default, and what the flags keep (with the
/// `clap` feature, `ciflow train`'s flags).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct Screening {
    /// Also train on demonstrations that failed their task (their last step is not a
    /// success: spilled, collided, never arrived); by default they are dropped.
    #[cfg_attr(feature = "clap", arg(long))]
    pub keep_failed: bool,
    /// Also fit the steps an external force moved (flagged `perturbed` in the data); by
    /// default they are left out of the likelihood, so the policy does not learn the push
    /// as its own motion.
    #[cfg_attr(feature = "clap", arg(long))]
    pub keep_perturbed: bool,
    /// Also leave out this many seconds after each pushed step, while the velocity the
    /// push left decays (the pouring expert's twist loop, 12 /s, takes 0.38 s to 1 %).
    /// Those steps are the expert's response to the pushed state, what pushed
    /// demonstrations are recorded to teach: leaving them out cost the pouring policy
    /// most of its recovery from pushes (README "Pouring").
    #[cfg_attr(
        feature = "clap",
        arg(long, default_value_t = 0.0, value_name = "SECONDS")
    )]
    pub push_settling: f64,
}

/// What [`demonstrations`] left out of a dataset.
#[derive(Clone, Debug, PartialEq)]
pub struct Screened {
    pub screening: Screening,
    /// Episodes in the dataset, and those of them that failed their task.
    pub recorded: usize,
    pub failed: usize,
    /// Transitions of the kept episodes, those an external force moved, and those left
    /// out of the likelihood (the moved ones and their settling steps).
    pub transitions: usize,
    pub perturbed: usize,
    pub excluded: usize,
    /// The settling window in control steps.
    pub settling_steps: usize,
}

impl fmt::Display for Screened {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Self {
            recorded,
            failed,
            transitions,
            perturbed,
            excluded,
            ..
        } = self;
        write!(f, "{failed} of {recorded} episodes failed their task")?;
        match (self.screening.keep_failed, failed) {
            (false, 0) => {}
            (false, _) => write!(f, " and are dropped (--keep-failed keeps them)")?,
            (true, _) => write!(f, ", kept (--keep-failed)")?,
        }
        write!(
            f,
            "; {perturbed} of {transitions} transitions moved by an external force"
        )?;
        match (self.screening.keep_perturbed, self.settling_steps) {
            (true, _) => write!(f, ", kept (--keep-perturbed)")?,
            (false, 0) => {}
            (false, steps) => write!(f, " (+ {steps} settling steps after each)")?,
        }
        write!(f, "; {excluded} left out of the likelihood")
    }
}

/// Which fields of a Minari or LeRobot dataset made by another tool are the policy's state
/// and context (with the `clap` feature, `ciflow train`'s flags for them).
#[derive(Clone, Debug, Default, PartialEq)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct ForeignFields {
    /// Train on a dataset made by another tool — Minari (HDF5 or Arrow storage, Box or
    /// Dict spaces) or LeRobot (v3.0, v2.x) — with this field as the state: a path and an
    /// optional column range, e.g. `observations[0:2]`, `observations/achieved_goal`,
    /// `observation.state[0:7]`. `python -m ciflow.convert` writes it into
    /// `<out>/demonstrations` first; the task names only the training recipe.
    #[cfg_attr(feature = "clap", arg(long, value_name = "FIELD"))]
    pub state: Option<String>,
    /// With --state: the field that is the context, one row per observation (e.g.
    /// observations/desired_goal, infos/goal) [default: none].
    #[cfg_attr(feature = "clap", arg(long, value_name = "FIELD", requires = "state"))]
    pub context: Option<String>,
    /// With --state: seconds between the dataset's observations, when it does not record
    /// them (LeRobot records 1/fps; given both ways, they must agree).
    #[cfg_attr(
        feature = "clap",
        arg(long, value_name = "SECONDS", requires = "state")
    )]
    pub dt: Option<f64>,
}

/// Where a go-to recipe (`recipe`: its target's context indices in `task`'s own data)
/// finds the target in a dataset made by another tool, whose context ciflow knows nothing
/// about: the whole context when it has the state's dimension; otherwise the user has to
/// say which entries it is (the recipe's own choice, the context's last entries, would be
/// a guess).
pub fn foreign_target(
    recipe: Option<Vec<usize>>,
    task: &str,
    state_dim: usize,
    context_dim: usize,
) -> TrainResult<Option<Vec<usize>>> {
    match recipe {
        None => Ok(None),
        Some(_) if context_dim == state_dim => Ok(Some((0..state_dim).collect())),
        Some(_) => {
            let example: Vec<String> = (0..state_dim).map(|i| i.to_string()).collect();
            Err(TrainError::InvalidConfig(format!(
                "the {task} recipe moves to a target read from the context, and this \
                 dataset's {context_dim}-D context is not the {state_dim}-D state's target: \
                 name the {state_dim} context entries that are, with --goal-context-indices \
                 (e.g. --goal-context-indices {})",
                example.join(",")
            )))
        }
    }
}

/// Converts the dataset at `source`, made by another tool, into `out` (the layout
/// [`read_foreign`] reads) with `python -m ciflow.convert`, which reads Minari datasets
/// with Minari's own loader and LeRobot ones with pyarrow. Returns `out`.
pub fn convert_foreign(source: &Path, out: &Path, fields: &ForeignFields) -> TrainResult<PathBuf> {
    let state = fields.state.as_deref().ok_or_else(|| {
        TrainError::InvalidConfig("a foreign dataset needs the field that is the state".into())
    })?;
    let mut args: Vec<std::ffi::OsString> = vec!["--overwrite".into(), "--state".into()];
    args.extend([state.into(), source.into(), out.into()]);
    if let Some(context) = &fields.context {
        args.extend(["--context".into(), context.into()]);
    }
    if let Some(dt) = fields.dt {
        args.extend(["--dt".into(), dt.to_string().into()]);
    }
    ciflow_envs::python::run_module("ciflow.convert", args).map_err(TrainError::Conversion)?;
    Ok(out.to_path_buf())
}

/// Reads the dataset at `dir` as `task`'s demonstrations (see [`demonstrations`]).
pub fn read(
    dir: &Path,
    task: &TaskEntry,
    screening: Screening,
) -> TrainResult<(DatasetSpec, Demonstrations, Screened)> {
    let (spec, episodes) = dataset::read(dir)?;
    let source = dir.display().to_string();
    recorded_on(&spec, task, &source)?;
    let (data, screened) = demonstrations(&spec, episodes, &source, screening)?;
    Ok((spec, data, screened))
}

/// Reads a dataset [`convert_foreign`] wrote, whose environment is not a ciflow task.
pub fn read_foreign(
    dir: &Path,
    screening: Screening,
) -> TrainResult<(DatasetSpec, Demonstrations, Screened)> {
    let (spec, episodes) = dataset::read(dir)?;
    let (data, screened) = demonstrations(&spec, episodes, &dir.display().to_string(), screening)?;
    Ok((spec, data, screened))
}

/// Refuses a dataset (from `source`, named in the error) recorded on another task.
pub fn recorded_on(spec: &DatasetSpec, task: &TaskEntry, source: &str) -> TrainResult<()> {
    if spec.env_id != task.id {
        return Err(TrainError::InvalidData(format!(
            "{source}: holds demonstrations of `{}` ({}), not of task `{}` ({})",
            spec.env_id, spec.dataset_id, task.name, task.id
        )));
    }
    Ok(())
}

/// The policy's demonstrations in dataset episodes (from `source`, named in errors):
/// positions `q` of each observation `[q, q̇, c]`, the per-step contexts,
/// `dt = control_dt`, screened as the module docs say.
pub fn demonstrations(
    spec: &DatasetSpec,
    episodes: Vec<dataset::Episode>,
    source: &str,
    screening: Screening,
) -> TrainResult<(Demonstrations, Screened)> {
    let invalid = |detail: String| Err(TrainError::InvalidData(format!("{source}: {detail}")));
    if !(screening.push_settling.is_finite() && screening.push_settling >= 0.0) {
        return Err(TrainError::InvalidConfig(format!(
            "the push settling window must be a finite number of seconds >= 0, not {}",
            screening.push_settling
        )));
    }
    let (observation_dim, context_dim) = (spec.observation_space.dim(), spec.context_space.dim());
    let velocity_and_position = observation_dim.saturating_sub(context_dim);
    if velocity_and_position == 0 || velocity_and_position % 2 != 0 {
        return invalid(format!(
            "observations of dimension {observation_dim} with a {context_dim}-D context are \
             not [q, q̇, c]"
        ));
    }
    let position_dim = velocity_and_position / 2;
    let recorded = episodes.len();
    let failed = episodes.iter().filter(|e| e.failed()).count();
    let kept: Vec<dataset::Episode> = episodes
        .into_iter()
        .filter(|e| screening.keep_failed || !e.failed())
        .collect();
    if kept.is_empty() {
        return invalid(format!(
            "all {recorded} episodes failed their task; --keep-failed trains on them"
        ));
    }
    let transitions = kept.iter().map(dataset::Episode::len).sum();
    let mut perturbed = 0;
    // A step is excluded when it or one of the `settling_steps` before it was pushed.
    let settling_steps = (screening.push_settling / spec.control_dt).round() as usize;
    let episodes: Vec<Episode> = kept
        .into_iter()
        .map(|episode| {
            let pushed: Vec<bool> = (0..episode.len()).map(|t| episode.perturbed(t)).collect();
            perturbed += pushed.iter().filter(|&&p| p).count();
            Episode {
                seed: episode.seed,
                excluded: (0..pushed.len())
                    .map(|t| {
                        !screening.keep_perturbed
                            && pushed[t.saturating_sub(settling_steps)..=t].contains(&true)
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
    let excluded = episodes
        .iter()
        .map(|e| e.excluded.iter().filter(|&&x| x).count())
        .sum();
    let screened = Screened {
        screening,
        recorded,
        failed,
        transitions,
        perturbed,
        excluded,
        settling_steps,
    };
    let data = Demonstrations {
        episodes,
        dt: spec.control_dt,
    };
    Ok((data, screened))
}

#[cfg(test)]
mod tests {
    use ciflow_envs::dataset::{DatasetSpec, Episode as Recorded};
    use ciflow_envs::env::{PERTURBED_INFO, SUCCESS_INFO};
    use ciflow_envs::registry;
    use ciflow_envs::space::{BoxSpace, Dtype};

    use super::{Screening, demonstrations, recorded_on};
    use crate::error::TrainError;

    /// A 1-D task's dataset spec: observations `[q, q̇, c]`, a 1-D context, 0.1 s steps.
    fn spec(env_id: &str) -> DatasetSpec {
        let space = |n| BoxSpace::new(vec![-1.0; n], vec![1.0; n], Dtype::Float64);
        DatasetSpec {
            dataset_id: "test/screening-v0".into(),
            env_id: env_id.into(),
            env_kwargs: Default::default(),
            observation_space: space(3),
            action_space: space(1),
            context_space: space(1),
            control_dt: 0.1,
            algorithm_name: "expert".into(),
            credits: Default::default(),
        }
    }

    /// Six steps with positions 0, 1, …, 6, pushed during `pushed` steps, ending in
    /// success or not.
    fn episode(pushed: &[usize], success: bool) -> Recorded {
        let steps = 6;
        let mut perturbed = vec![0.0; steps + 1];
        for &t in pushed {
            perturbed[t + 1] = 1.0;
        }
        let mut is_success = vec![0.0; steps + 1];
        is_success[steps] = f64::from(u8::from(success));
        Recorded {
            observations: (0..=steps).map(|t| vec![t as f64, 1.0, 0.5]).collect(),
            actions: vec![vec![0.0]; steps],
            rewards: vec![0.0; steps],
            terminations: vec![false; steps],
            truncations: vec![false; steps],
            contexts: vec![vec![0.5]; steps + 1],
            infos: [
                (PERTURBED_INFO.to_string(), perturbed),
                (SUCCESS_INFO.to_string(), is_success),
            ]
            .into(),
            ..Recorded::default()
        }
    }

    const DEFAULT: Screening = Screening {
        keep_failed: false,
        keep_perturbed: false,
        push_settling: 0.2,
    };

    #[test]
    fn failed_episodes_are_dropped_and_pushed_steps_with_their_settling_window_excluded() {
        let task = registry::entry("limit-cycle").unwrap();
        let recorded = vec![episode(&[1], true), episode(&[], false)];
        let (data, screened) =
            demonstrations(&spec(task.id), recorded.clone(), "test", DEFAULT).unwrap();
        assert_eq!(data.episodes.len(), 1);
        assert_eq!(data.episodes[0].states[3], [3.0], "positions only");
        // Step 1 pushed, steps 2 and 3 within the 0.2 s settling window.
        let excluded = [false, true, true, true, false, false];
        assert_eq!(data.episodes[0].excluded, excluded);
        assert_eq!(
            (
                screened.failed,
                screened.perturbed,
                screened.excluded,
                screened.settling_steps
            ),
            (1, 1, 3, 2)
        );
        let keep_all = Screening {
            keep_failed: true,
            keep_perturbed: true,
            ..DEFAULT
        };
        let (data, screened) = demonstrations(&spec(task.id), recorded, "test", keep_all).unwrap();
        assert_eq!(data.episodes.len(), 2);
        assert!(data.episodes.iter().flat_map(|e| &e.excluded).all(|&x| !x));
        assert_eq!(screened.excluded, 0);
        assert!(
            screened.to_string().contains("kept (--keep-failed)"),
            "{screened}"
        );
    }

    #[test]
    fn another_task_s_data_and_all_failed_data_are_refused() {
        let task = registry::entry("limit-cycle").unwrap();
        let other = recorded_on(&spec("ciflow/Pouring-v0"), task, "test");
        assert!(matches!(other, Err(TrainError::InvalidData(m)) if m.contains("Pouring")));
        let failed = demonstrations(&spec(task.id), vec![episode(&[], false)], "t", DEFAULT);
        assert!(matches!(failed, Err(TrainError::InvalidData(m)) if m.contains("--keep-failed")));
        let never_settles = Screening {
            push_settling: f64::NAN,
            ..DEFAULT
        };
        let nan = demonstrations(&spec(task.id), vec![episode(&[], true)], "t", never_settles);
        assert!(matches!(nan, Err(TrainError::InvalidConfig(_))));
    }
}
