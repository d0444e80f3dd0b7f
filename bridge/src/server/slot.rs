//! One environment inside a session, with the bookkeeping the protocol reports: simulated
//! time, the last command, and whether the episode ended (for next-step autoreset).

use ciflow_envs::env::PERTURBED_INFO;
use ciflow_envs::{Env, EnvError, Info, ResetOptions, StepOutcome};

pub(crate) struct EnvSlot {
    pub env: Box<dyn Env>,
    /// Control periods since the last reset.
    pub steps: u64,
    /// The last action applied (zeros after a reset).
    pub command: Vec<f64>,
    pub observation: Vec<f64>,
    pub reward: f64,
    /// `true` after a step that terminated or truncated, until the next reset.
    pub episode_over: bool,
    /// An external force acted during the last step (the task's [`PERTURBED_INFO`];
    /// false for tasks that do not report it).
    pub perturbed: bool,
}

impl EnvSlot {
    pub fn new(env: Box<dyn Env>) -> Self {
        let action_dim = env.spec().action_space.dim();
        Self {
            env,
            steps: 0,
            command: vec![0.0; action_dim],
            observation: Vec::new(),
            reward: 0.0,
            episode_over: false,
            perturbed: false,
        }
    }

    /// Simulated seconds since the reset: `steps · control_dt`.
    pub fn time(&self) -> f64 {
        self.steps as f64 * self.env.spec().control_dt
    }

    pub fn reset(
        &mut self,
        seed: Option<u64>,
        options: &ResetOptions,
    ) -> Result<(Vec<f64>, Info), EnvError> {
        let (observation, info) = self.env.reset(seed, options)?;
        self.steps = 0;
        self.command.iter_mut().for_each(|c| *c = 0.0);
        self.observation.clone_from(&observation);
        self.reward = 0.0;
        self.episode_over = false;
        self.perturbed = pushed(&info);
        Ok((observation, info))
    }

    /// Whether the environment must be reset before it steps: never reset, or its episode
    /// ended.
    pub fn needs_reset(&self) -> bool {
        self.observation.is_empty() || self.episode_over
    }

    /// One control period; the new observation is [`observation`](Self::observation), its
    /// info replaces `info`'s. The action is checked here too, so that a task that forgets
    /// a check still answers with a typed error.
    pub fn step(&mut self, action: &[f64], info: &mut Info) -> Result<StepOutcome, EnvError> {
        check_vector("action", action, self.command.len())?;
        if self.needs_reset() {
            return Err(EnvError::NeedsReset);
        }
        let outcome = self.env.step_into(action, &mut self.observation, info)?;
        self.steps += 1;
        self.command.copy_from_slice(action);
        self.reward = outcome.reward;
        self.episode_over = outcome.terminated || outcome.truncated;
        self.perturbed = pushed(info);
        Ok(outcome)
    }

    /// A step with Gymnasium's next-step autoreset: if the previous step ended the
    /// episode, the action is ignored and the environment resets instead (RNG continuing),
    /// its reset info in `info`.
    pub fn step_autoreset(
        &mut self,
        action: &[f64],
        options: &ResetOptions,
        info: &mut Info,
    ) -> Result<StepOutcome, EnvError> {
        if !self.episode_over {
            return self.step(action, info);
        }
        (_, *info) = self.reset(None, options)?;
        Ok(StepOutcome {
            reward: 0.0,
            terminated: false,
            truncated: false,
        })
    }

    /// The context: the tail of the observation, as [`ciflow_envs::EnvSpec`] defines it.
    pub fn context(&self) -> &[f64] {
        let context_dim = self.env.spec().context_space.dim();
        let split = self.observation.len().saturating_sub(context_dim);
        &self.observation[split..]
    }

    /// The observation without its context tail.
    pub fn state(&self) -> &[f64] {
        let context_dim = self.env.spec().context_space.dim();
        &self.observation[..self.observation.len().saturating_sub(context_dim)]
    }
}

fn pushed(info: &Info) -> bool {
    info.get(PERTURBED_INFO).is_some_and(|&flag| flag > 0.0)
}

/// `values` must have `expected` finite elements.
pub(crate) fn check_vector(
    what: &'static str,
    values: &[f64],
    expected: usize,
) -> Result<(), EnvError> {
    if values.len() != expected {
        return Err(EnvError::WrongDimension {
            what,
            expected,
            got: values.len(),
        });
    }
    if values.iter().any(|v| !v.is_finite()) {
        return Err(EnvError::NotFinite { what });
    }
    Ok(())
}
