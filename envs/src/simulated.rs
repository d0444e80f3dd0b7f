//! [`SimulatedEpisode`]: what the planar and the arm environments keep of an episode of
//! their robot under the [`Simulator`], and the parts of `reset` and `step` they take
//! alike.
//!
//! A step is the same for every task: check the action against the spec, advance the
//! simulator one control period (`q̈ = a + M⁻¹ τ_ext` through computed torque), record the
//! point `render` traces, write the observation `[q, q̇, c]`, and end the episode when the
//! task's outcome terminates it or the step count reaches `max_episode_steps`. What differs
//! between tasks (the point traced, the outcome) comes in between
//! ([`advance`](SimulatedEpisode::advance), then [`finish_step`](SimulatedEpisode::finish_step)).

use ciflow_engine::sim::{Perturbation, Simulator};

use crate::env::{EnvError, EnvSpec, Outcome, Phase, StepOutcome};
use crate::seeding::EpisodeRng;
use crate::trail::Trail;

/// A robot's episode under the [`Simulator`]; `P` is the point its trail records.
pub(crate) struct SimulatedEpisode<P> {
    pub simulator: Simulator,
    /// The RNG of `reset` (Gymnasium's seeding rule).
    pub rng: EpisodeRng,
    /// The context of the episode: the tail of every observation.
    pub context: Vec<f64>,
    pub phase: Phase,
    /// Control periods taken this episode.
    steps: u32,
    /// The traced point's positions this episode, drawn by `render`.
    trail: Trail<P>,
}

impl<P> SimulatedEpisode<P> {
    /// The robot of `simulator`, never reset: only `reset` is allowed.
    pub fn new(simulator: Simulator) -> Self {
        Self {
            simulator,
            rng: EpisodeRng::default(),
            context: Vec::new(),
            phase: Phase::NeedsReset,
            steps: 0,
            trail: Trail::default(),
        }
    }

    /// Starts an episode from the simulator's state as reset, with `first` the traced
    /// point there.
    pub fn start(&mut self, first: P, max_episode_steps: u32) {
        self.phase = Phase::Running;
        self.steps = 0;
        self.trail.start(first, max_episode_steps);
    }

    /// The first half of a step: refuses unless an episode runs, `action` lies in the
    /// action space and `observation` has the observation's length, then advances the
    /// simulator one control period under `action`.
    pub fn advance(
        &mut self,
        spec: &EnvSpec,
        action: &[f64],
        observation: &[f64],
    ) -> Result<(), EnvError> {
        self.phase.running()?;
        spec.action_space.check("action", action)?;
        spec.check_observation_buffer(observation)?;
        self.simulator.step(action).map_err(EnvError::Simulation)?;
        self.steps += 1;
        Ok(())
    }

    /// The second half, once the task has judged the new state: `point` traced, the
    /// observation written into `observation`, and the episode ended if `outcome`
    /// terminates it or its steps reach `max_episode_steps`.
    pub fn finish_step(
        &mut self,
        point: P,
        outcome: Outcome,
        max_episode_steps: u32,
        observation: &mut [f64],
    ) -> StepOutcome {
        self.trail.push(point);
        self.write_observation(observation);
        self.phase
            .finish_step(outcome, self.steps, max_episode_steps)
    }

    /// The observation `[q, q̇, c]` of the robot's state and the context, the layout of
    /// every task ([`EnvSpec::position_dim`]).
    pub fn observation(&self) -> Vec<f64> {
        let (q, qd) = (self.simulator.q(), self.simulator.qd());
        let mut observation = vec![0.0; q.len() + qd.len() + self.context.len()];
        self.write_observation(&mut observation);
        observation
    }

    /// [`observation`](Self::observation) written into `buffer`, which has its length.
    fn write_observation(&self, buffer: &mut [f64]) {
        let (q, rest) = buffer.split_at_mut(self.simulator.q().len());
        let (qd, c) = rest.split_at_mut(self.simulator.qd().len());
        q.copy_from_slice(self.simulator.q().as_slice());
        qd.copy_from_slice(self.simulator.qd().as_slice());
        c.copy_from_slice(&self.context);
    }

    /// Applies `perturbation` to the robot, once an episode has started.
    pub fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
        self.phase.started()?;
        self.simulator
            .perturb(perturbation)
            .map_err(EnvError::InvalidPerturbation)
    }

    pub fn trail(&self) -> &[P] {
        self.trail.points()
    }

    /// Starts or stops recording the trail (see [`Trail::record`]).
    pub fn record_trail(&mut self, recording: bool) {
        self.trail.record(recording);
    }
}
