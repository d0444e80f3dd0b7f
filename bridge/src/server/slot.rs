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
    /// a check still answers with a typed error; and `info` is cleared here too, so that a
    /// task that forgets to clear it does not pass the keys of the environment stepped
    /// before (in a batch, the same `info` goes from one environment to the next) on as
    /// its own.
    pub fn step(&mut self, action: &[f64], info: &mut Info) -> Result<StepOutcome, EnvError> {
        check_vector("action", action, self.command.len())?;
        if self.needs_reset() {
            return Err(EnvError::NeedsReset);
        }
        info.clear();
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

#[cfg(test)]
mod tests {
    use ciflow_engine::sim::Perturbation;
    use ciflow_envs::EnvSpec;
    use ciflow_envs::scene::Scene;

    use super::*;

    /// A task that adds its step's info to whatever `info` held, as a user's task that
    /// forgets to clear it would: a built-in task underneath.
    struct Forgetful(Box<dyn Env>);

    impl Env for Forgetful {
        fn spec(&self) -> &EnvSpec {
            self.0.spec()
        }

        fn reset(
            &mut self,
            seed: Option<u64>,
            options: &ResetOptions,
        ) -> Result<(Vec<f64>, Info), EnvError> {
            self.0.reset(seed, options)
        }

        fn step_into(
            &mut self,
            action: &[f64],
            observation: &mut [f64],
            info: &mut Info,
        ) -> Result<StepOutcome, EnvError> {
            let mut own = Info::new();
            let outcome = self.0.step_into(action, observation, &mut own)?;
            info.extend(own.iter().map(|(key, value)| (key.clone(), *value)));
            Ok(outcome)
        }

        fn expert_action(&self) -> Result<Vec<f64>, EnvError> {
            self.0.expert_action()
        }

        fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
            self.0.set_context(context)
        }

        fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
            self.0.perturb(perturbation)
        }

        fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError> {
            self.0.render(width, height)
        }

        fn record_trail(&mut self, recording: bool) {
            self.0.record_trail(recording);
        }

        fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError> {
            self.0.scene(observation)
        }
    }

    /// The info a step leaves is that step's alone, even from a task that does not clear
    /// it; the same task stepped directly keeps the stale key, so the test can see one.
    #[test]
    fn a_step_reports_only_its_own_info_even_from_a_task_that_forgets_to_clear_it() {
        let task = || Forgetful(ciflow_envs::make("ciflow/Obstacle-v0").unwrap());
        let stale = || -> Info { [("stale".into(), 1.0)].into_iter().collect() };
        let mut slot = EnvSlot::new(Box::new(task()));
        slot.reset(Some(3), &ResetOptions::default()).unwrap();
        let action = vec![0.0; slot.command.len()];
        let mut info = stale();
        slot.step(&action, &mut info).unwrap();
        assert!(info.get("stale").is_none(), "a stale key in {info:?}");
        assert!(!info.is_empty(), "the task's own info");

        let mut direct = task();
        direct.reset(Some(3), &ResetOptions::default()).unwrap();
        let mut observation = slot.observation.clone();
        let mut info = stale();
        direct
            .step_into(&action, &mut observation, &mut info)
            .unwrap();
        assert!(
            info.get("stale").is_some(),
            "the control keeps the stale key"
        );
    }
}
