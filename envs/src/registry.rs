//! Task ids and constructors: the one place that knows which tasks exist.

use std::collections::BTreeMap;

use ciflow_engine::robot::Robot;
use ciflow_engine::training::TrainConfig;

use crate::env::{Env, EnvError};
use crate::recipes::{self, ContextWithoutTarget};
use crate::tasks::{lasa, limit_cycle, obstacle_avoidance, pouring, reach};

pub use crate::kwargs::{Kwarg, Kwargs, TextArgument};

/// Builds the arm a task drives with these construction arguments.
pub type MakeRobot = fn(&Kwargs) -> Result<Box<dyn Robot>, EnvError>;

/// Points along the curve a task's motion should trace, for a context.
pub type ReferenceCurve = fn(&[f64]) -> Vec<[f64; 2]>;

/// A registered task: its Gymnasium id and how to build it.
pub struct TaskEntry {
    /// Gymnasium id, e.g. `ciflow/Pouring-v0`.
    pub id: &'static str,
    /// Short name used on the command line, e.g. `pouring`.
    pub name: &'static str,
    /// One line for `--help` and listings.
    pub summary: &'static str,
    /// Builds the task with its default arguments.
    pub make: fn() -> Box<dyn Env>,
    /// Builds the task with construction arguments (see each task's "Arguments").
    pub make_with: fn(&Kwargs) -> Result<Box<dyn Env>, EnvError>,
    /// Arguments and options whose values may be given by name: `(key, names)`, where a
    /// name stands for its index in `names` (e.g. LASA's `shape`).
    pub named_values: &'static [(&'static str, &'static [&'static str])],
    /// Construction arguments that are texts (the reach task's `urdf`); all others are
    /// numbers.
    pub text_arguments: &'static [TextArgument],
    /// The closed curve a 2-D task's motion should trace for a context (the limit
    /// cycle's outline), drawn beside learned fields; `None` for go-to tasks.
    pub reference_curve: Option<ReferenceCurve>,
    /// Context coordinates with a physical range that the training contexts already span
    /// (angles, the limit cycle's phase): checks that extrapolate the context keep these
    /// inside the training box and scale the others (positions).
    pub bounded_context: &'static [usize],
    /// The movable link the evaluation pushes by default with the task's default
    /// arguments: the hand of an arm (its last link), the body of a point mass; see
    /// [`TaskEntry::pushed_link_with`] for other arguments.
    pub pushed_link: usize,
    /// The context entries a mid-motion change replaces by default: the last `n` (the
    /// obstacle-avoidance target, while its obstacles stay), or all of them (`None`).
    pub moved_context_tail: Option<usize>,
    /// The arm the task built with these construction arguments drives, with its real
    /// limits (pouring: the Panda; reach: the arm of its URDF); `None` for the planar
    /// tasks' point mass, whose workspace each check chooses.
    pub robot: Option<MakeRobot>,
    /// How the task's policy is trained unless told otherwise, for a context of the
    /// given dimension ([`recipes`]); use [`TaskEntry::training_recipe`].
    pub training: fn(&'static str, usize) -> Result<TrainConfig, ContextWithoutTarget>,
}

impl TaskEntry {
    /// The task's training recipe for a `context_dim`-D context.
    pub fn training_recipe(&self, context_dim: usize) -> Result<TrainConfig, ContextWithoutTarget> {
        (self.training)(self.name, context_dim)
    }

    /// The number an argument or option `key` of this task takes for `text`: `text` as a
    /// number, or the index of a name listed in [`TaskEntry::named_values`].
    pub fn value(&self, key: &str, text: &str) -> Result<f64, EnvError> {
        if let Ok(number) = text.parse::<f64>() {
            return Ok(number);
        }
        let names = self
            .named_values
            .iter()
            .find(|(named, _)| *named == key)
            .map(|(_, names)| *names);
        let invalid = |detail: String| EnvError::InvalidOption {
            name: key.into(),
            detail,
        };
        match names {
            Some(names) => names
                .iter()
                .position(|n| *n == text)
                .map(|i| i as f64)
                .ok_or_else(|| invalid(format!("`{text}` is none of {}", names.join(", ")))),
            None => Err(invalid(format!("`{text}` is not a number"))),
        }
    }

    /// The link the evaluation pushes by default on the task built with `kwargs`: an arm's
    /// last link (the reach task's depends on its URDF), else [`TaskEntry::pushed_link`].
    pub fn pushed_link_with(&self, kwargs: &Kwargs) -> Result<usize, EnvError> {
        match self.robot {
            Some(arm) => Ok(arm(kwargs)?.link_count() - 1),
            None => Ok(self.pushed_link),
        }
    }

    /// `NAME=VALUE` pairs of reset options as numbers ([`Self::value`] of each).
    pub fn values(&self, pairs: &[(String, String)]) -> Result<BTreeMap<String, f64>, EnvError> {
        pairs
            .iter()
            .map(|(key, text)| Ok((key.clone(), self.value(key, text)?)))
            .collect()
    }

    /// The construction argument `key` for `text`: the text itself (a file's content for
    /// a file argument) if the task takes `key` as text, else [`Self::value`].
    pub fn argument(&self, key: &str, text: &str) -> Result<Kwarg, EnvError> {
        match self.text_arguments.iter().find(|a| a.key == key) {
            Some(argument) if argument.file => document(key, text).map(Kwarg::Text),
            Some(_) => Ok(Kwarg::Text(text.to_owned())),
            None => self.value(key, text).map(Kwarg::Number),
        }
    }

    /// `NAME=VALUE` pairs of construction arguments ([`Self::argument`] of each).
    pub fn arguments(&self, pairs: &[(String, String)]) -> Result<Kwargs, EnvError> {
        pairs
            .iter()
            .map(|(key, text)| Ok((key.clone(), self.argument(key, text)?)))
            .collect()
    }
}

/// A document given in full (its first non-blank character is `<`, as in any XML) or as
/// the path of a file holding it.
fn document(key: &str, text: &str) -> Result<String, EnvError> {
    if text.trim_start().starts_with('<') {
        return Ok(text.to_owned());
    }
    std::fs::read_to_string(text).map_err(|e| EnvError::InvalidOption {
        name: key.into(),
        detail: format!("cannot read `{text}`: {e}"),
    })
}

fn unknown_kwargs(kwargs: &Kwargs, known: &[&str]) -> Result<(), EnvError> {
    crate::planar::reject_unknown_options(kwargs, known)
}

fn limit_cycle_with(kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    unknown_kwargs(kwargs, &[])?;
    Ok(Box::new(limit_cycle::make()?))
}

fn obstacle_avoidance_with(kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    let name = obstacle_avoidance::OBSTACLES_OPTION;
    unknown_kwargs(kwargs, &[name])?;
    let count =
        crate::kwargs::number(kwargs, name)?.unwrap_or(obstacle_avoidance::MAX_OBSTACLES as f64);
    if count.fract() != 0.0 || count < 0.0 {
        return Err(EnvError::InvalidOption {
            name: name.into(),
            detail: format!("{count} is not a whole number"),
        });
    }
    Ok(Box::new(obstacle_avoidance::make(count as usize)?))
}

fn lasa_with(kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    let name = lasa::SHAPE_OPTION;
    unknown_kwargs(kwargs, &[name])?;
    let numbers = crate::kwargs::number(kwargs, name)?
        .map(|shape| BTreeMap::from([(name.to_owned(), shape)]))
        .unwrap_or_default();
    let shape = crate::planar::index_option(&numbers, name, lasa::SHAPES.len())?.unwrap_or(0);
    Ok(Box::new(lasa::make(shape)?))
}

fn pouring_with(kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    unknown_kwargs(kwargs, &[])?;
    Ok(Box::new(pouring::make()?))
}

fn reach_with(kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(reach::make(kwargs)?))
}

/// Defaults never fail: each task's tests build it with its defaults.
fn with_defaults(make_with: fn(&Kwargs) -> Result<Box<dyn Env>, EnvError>) -> Box<dyn Env> {
    make_with(&Kwargs::new()).expect("a task's default arguments are valid (tested)")
}

/// Every task this build provides.
pub fn tasks() -> &'static [TaskEntry] {
    &[
        TaskEntry {
            id: limit_cycle::ID,
            name: "limit-cycle",
            summary: "Vitruvian-man limit cycles of a 2-D point mass, context = phase",
            make: || with_defaults(limit_cycle_with),
            make_with: limit_cycle_with,
            named_values: &[],
            text_arguments: &[],
            reference_curve: Some(limit_cycle::outline_curve),
            bounded_context: &[0],
            pushed_link: 0,
            moved_context_tail: None,
            robot: None,
            training: recipes::limit_cycle,
        },
        TaskEntry {
            id: obstacle_avoidance::ID,
            name: "obstacle-avoidance",
            summary: "2-D go-to among 1-3 obstacles, context = obstacles + target",
            make: || with_defaults(obstacle_avoidance_with),
            make_with: obstacle_avoidance_with,
            named_values: &[],
            text_arguments: &[],
            reference_curve: None,
            bounded_context: &[],
            pushed_link: 0,
            moved_context_tail: Some(2),
            robot: None,
            training: recipes::obstacle_avoidance,
        },
        TaskEntry {
            id: pouring::ID,
            name: "pouring",
            summary: "7-DOF Panda pours from a cup into a pot, context = the pot's 6-D pose",
            make: || with_defaults(pouring_with),
            make_with: pouring_with,
            named_values: &[],
            text_arguments: &[],
            reference_curve: None,
            bounded_context: &[3, 4, 5],
            pushed_link: pouring::HAND_LINK,
            moved_context_tail: None,
            robot: Some(|_| Ok(pouring::robot())),
            training: recipes::pouring,
        },
        TaskEntry {
            id: reach::ID,
            name: "reach",
            summary: "any serial arm from its URDF (default: the Panda) brings its tool to a \
                      goal, context = the goal's position",
            make: || with_defaults(reach_with),
            make_with: reach_with,
            named_values: &[],
            text_arguments: &reach::TEXT_ARGUMENTS,
            reference_curve: None,
            bounded_context: &[],
            pushed_link: pouring::HAND_LINK,
            moved_context_tail: None,
            robot: Some(reach::robot),
            training: recipes::reach,
        },
        TaskEntry {
            id: lasa::ID,
            name: "lasa",
            summary: "the 30 LASA handwriting shapes as 2-D go-to motions (mm), context = goal",
            make: || with_defaults(lasa_with),
            make_with: lasa_with,
            named_values: &[(lasa::SHAPE_OPTION, &lasa::SHAPES)],
            text_arguments: &[],
            reference_curve: None,
            bounded_context: &[],
            pushed_link: 0,
            moved_context_tail: None,
            robot: None,
            training: recipes::lasa,
        },
    ]
}

/// The registered task with this Gymnasium id or command-line name.
pub fn entry(id_or_name: &str) -> Result<&'static TaskEntry, EnvError> {
    tasks()
        .iter()
        .find(|t| t.id == id_or_name || t.name == id_or_name)
        .ok_or_else(|| EnvError::InvalidOption {
            name: "task".into(),
            detail: format!(
                "unknown task `{id_or_name}`; known: {}",
                tasks()
                    .iter()
                    .map(|t| t.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        })
}

/// Builds the task with this Gymnasium id or command-line name.
pub fn make(id_or_name: &str) -> Result<Box<dyn Env>, EnvError> {
    entry(id_or_name).map(|t| (t.make)())
}

/// Builds the task with construction arguments, like `gymnasium.make(id, **kwargs)`.
pub fn make_with(id_or_name: &str, kwargs: &Kwargs) -> Result<Box<dyn Env>, EnvError> {
    (entry(id_or_name)?.make_with)(kwargs)
}
