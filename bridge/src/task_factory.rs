//! The tasks an engine can instantiate: the registry's, or any other built by a closure
//! (tests serve fixture tasks this way).

use std::sync::Arc;

use ciflow_envs::registry::Kwargs;
use ciflow_envs::{Env, EnvError};

/// Builds a task from construction arguments.
pub type MakeFn = dyn Fn(&Kwargs) -> Result<Box<dyn Env>, EnvError> + Send + Sync;

/// A task the engine can instantiate.
#[derive(Clone)]
pub struct TaskFactory {
    /// Gymnasium id, e.g. `ciflow/Pouring-v0`.
    pub id: String,
    /// Short name, e.g. `pouring`.
    pub name: String,
    pub make: Arc<MakeFn>,
}

impl TaskFactory {
    /// Every task of `ciflow_envs::tasks()`.
    pub fn registry() -> Vec<TaskFactory> {
        ciflow_envs::tasks()
            .iter()
            .map(|entry| TaskFactory {
                id: entry.id.to_owned(),
                name: entry.name.to_owned(),
                make: Arc::new(entry.make_with),
            })
            .collect()
    }

    /// Whether `task` names this task: its Gymnasium id or its short name.
    pub fn is_named(&self, task: &str) -> bool {
        self.id == task || self.name == task
    }
}
