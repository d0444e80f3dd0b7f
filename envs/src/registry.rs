//! Task ids and constructors: the one place that knows which tasks exist.

use crate::env::{Env, EnvError};

/// A registered task: its Gymnasium id and how to build it.
pub struct TaskEntry {
    /// Gymnasium id, e.g. `ciflow/Pouring-v0`.
    pub id: &'static str,
    /// Short name used on the command line, e.g. `pouring`.
    pub name: &'static str,
    pub make: fn() -> Box<dyn Env>,
}

/// Every task this build provides.
pub fn tasks() -> &'static [TaskEntry] {
    &[]
}

/// Builds the task with this Gymnasium id or command-line name.
pub fn make(id_or_name: &str) -> Result<Box<dyn Env>, EnvError> {
    tasks()
        .iter()
        .find(|t| t.id == id_or_name || t.name == id_or_name)
        .map(|t| (t.make)())
        .ok_or_else(|| EnvError::InvalidOption {
            name: "task".into(),
            detail: format!(
                "unknown task `{id_or_name}`; known: {}",
                tasks().iter().map(|t| t.name).collect::<Vec<_>>().join(", ")
            ),
        })
}
