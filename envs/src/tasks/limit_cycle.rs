//! `ciflow/LimitCycle-v0` — the conditioned "Vitruvian man" of the C-IFlows paper.
//!
//! ## Description
//! A 1 kg point mass in the plane should circulate along the outline of a human figure
//! whose arms and legs move with a context `c ∈ [0, 2]` ([`Outline`]): on `[0, 1]` (the
//! paper's phases) arms from slightly below horizontal (`c = 0`) to raised (`c = 1`), legs
//! spreading apart; on `[1, 2]` the raised figure curls its limbs into hooks, outlines no
//! longer star-shaped about the centre from `c ≈ 1.15` on (a ray from it crosses the
//! outline three times, from `c ≈ 1.8` five). Each
//! outline is a simple closed curve, the stable limit cycle of the expert.
//!
//! ## Action space
//! `Box(-60, 60, (2,), float64)`: desired acceleration `ẍ_des` (m/s²) through the
//! computed-torque layer; out-of-range actions are refused with `OutOfBounds`.
//!
//! ## Observation space
//! `[x, y, ẋ, ẏ, c]`: position (m), velocity (m/s), the context `c` (unitless, `[0, 2]`).
//!
//! ## Context distribution
//! Option `context_set`: `0` (default) the ten training phases [`TRAINING_CONTEXTS`]
//! `= {0, 0.1, 0.2, 0.3, 0.4, 0.6, 0.7, 0.8, 0.9, 1}`; `1` the held-out phases
//! [`HELD_OUT_CONTEXTS`] `= {0.25, 0.5, 0.75}`; `2` uniform on `[0, 1]`; `3` and `4` the
//! curled outlines of the same sets shifted by one ([`CURLED_TRAINING_CONTEXTS`]
//! `= {1, 1.1, …, 1.4, 1.6, …, 2}`, [`CURLED_HELD_OUT_CONTEXTS`] `= {1.25, 1.5, 1.75}`).
//! The finite sets are scheduled, not drawn: a reset with seed `s` takes phase `s mod n` of its set
//! and each unseeded reset the next one, so the episodes of seeds `s, s + 1, …` (how
//! `ciflow demos` and `python -m ciflow.record` seed them) demonstrate every phase once
//! before any repeats. `options.context` sets it directly.
//!
//! ## Expert
//! [`LimitCycleField`] (converge onto the outline, circulate counter-clockwise at 0.8 m/s
//! along the star-shaped figures, that field carried through the curl for curled ones)
//! tracked with `k_v = 25 /s`, clipped to the action space.
//!
//! ## Rewards
//! `−d(x, outline)`, the Euclidean distance to the outline (m). `info`: `outline_error`
//! (that distance), `is_success` (1 when it is below 3 cm), `time` (s).
//!
//! ## Starting state
//! Position uniform in `[−1.2, 1.2]²` at least 0.2 m from the figure's centre; zero
//! velocity. `options.initial_position` / `initial_velocity` override them.
//!
//! ## Episode end
//! Never terminates (a limit cycle has no end); truncated after 1000 steps (10 s).
//!
//! ## Arguments
//! None.
//!
//! ## Version history
//! v0: initial version.

use std::collections::BTreeMap;

use nalgebra::Vector2;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::env::{EnvError, Info, Outcome, SUCCESS_INFO};
use crate::expert::limit_cycle::LimitCycleField;
use crate::expert::tracking::VelocityField;
use crate::planar::{PlanarEnv, PlanarSetup, PlanarTask, reject_unknown_options};
use crate::raster::{Canvas, GREY, View};
use crate::scene::{Body, Shape, planar};
use crate::space::{BoxSpace, Dtype};
use crate::vitruvian::Outline;

pub const ID: &str = "ciflow/LimitCycle-v0";
/// The ten phases demonstrated for training, as in the paper: `0.5`, the phase the
/// paper's figure shows as unseen, is left out.
pub const TRAINING_CONTEXTS: [f64; 10] = [0.0, 0.1, 0.2, 0.3, 0.4, 0.6, 0.7, 0.8, 0.9, 1.0];
/// Phases between the training ones, for generalisation tests (the paper shows 0.5).
pub const HELD_OUT_CONTEXTS: [f64; 3] = [0.25, 0.5, 0.75];
/// The curled outlines' contexts: the same schedule one further.
pub const CURLED_TRAINING_CONTEXTS: [f64; 10] = [1.0, 1.1, 1.2, 1.3, 1.4, 1.6, 1.7, 1.8, 1.9, 2.0];
pub const CURLED_HELD_OUT_CONTEXTS: [f64; 3] = [1.25, 1.5, 1.75];
/// Distance to the outline below which the mass counts as on it, m.
pub const SUCCESS_DISTANCE: f64 = 0.03;
const CONTEXT_SET_OPTION: &str = "context_set";
const MIN_START_RADIUS: f64 = 0.2;

/// Where `reset` draws the phase from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContextSet {
    Training,
    HeldOut,
    Uniform,
    CurledTraining,
    CurledHeldOut,
}

/// The limit-cycle task (see the module docs).
pub struct LimitCycle {
    setup: PlanarSetup,
    context_space: BoxSpace,
    context_set: ContextSet,
    /// Where the next unseeded reset is in its set's schedule.
    next_in_schedule: usize,
    field: LimitCycleField,
}

impl Default for LimitCycle {
    fn default() -> Self {
        Self {
            setup: PlanarSetup {
                id: ID,
                workspace: View {
                    min: Vector2::new(-1.2, -1.2),
                    max: Vector2::new(1.2, 1.2),
                },
                max_acceleration: 60.0,
                control_dt: 0.01,
                physics_dt: 0.001,
                max_episode_steps: 1000,
            },
            context_space: BoxSpace::new(vec![0.0], vec![2.0], Dtype::Float64),
            context_set: ContextSet::Training,
            next_in_schedule: 0,
            field: LimitCycleField {
                outline: Outline::shared(0.0),
            },
        }
    }
}

/// Points along the outline of context `context[0]`, closed (the first point repeated).
pub fn outline_curve(context: &[f64]) -> Vec<[f64; 2]> {
    let mut points: Vec<[f64; 2]> = Outline::new(context[0])
        .polyline(OUTLINE_POINTS)
        .iter()
        .map(|p| [p.x, p.y])
        .collect();
    points.push(points[0]);
    points
}

/// Points of [`outline_curve`].
const OUTLINE_POINTS: usize = 400;

/// The environment.
pub fn make() -> Result<PlanarEnv<LimitCycle>, EnvError> {
    PlanarEnv::new(LimitCycle::default())
}

impl LimitCycle {
    pub fn outline(&self) -> &Outline {
        &self.field.outline
    }
}

impl PlanarTask for LimitCycle {
    fn setup(&self) -> &PlanarSetup {
        &self.setup
    }

    fn context_space(&self) -> &BoxSpace {
        &self.context_space
    }

    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError> {
        reject_unknown_options(extra, &[CONTEXT_SET_OPTION])?;
        self.context_set = match extra.get(CONTEXT_SET_OPTION).copied() {
            None => ContextSet::Training,
            Some(0.0) => ContextSet::Training,
            Some(1.0) => ContextSet::HeldOut,
            Some(2.0) => ContextSet::Uniform,
            Some(3.0) => ContextSet::CurledTraining,
            Some(4.0) => ContextSet::CurledHeldOut,
            Some(v) => {
                return Err(EnvError::InvalidOption {
                    name: CONTEXT_SET_OPTION.into(),
                    detail: format!(
                        "{v} is not 0 (training), 1 (held out), 2 (uniform), 3 (curled \
                         training) or 4 (curled held out)"
                    ),
                });
            }
        };
        Ok(())
    }

    fn sample_context(&mut self, seed: Option<u64>, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let schedule: &[f64] = match self.context_set {
            ContextSet::Training => &TRAINING_CONTEXTS,
            ContextSet::HeldOut => &HELD_OUT_CONTEXTS,
            ContextSet::CurledTraining => &CURLED_TRAINING_CONTEXTS,
            ContextSet::CurledHeldOut => &CURLED_HELD_OUT_CONTEXTS,
            ContextSet::Uniform => return vec![rng.random_range(0.0..=1.0)],
        };
        let n = schedule.len();
        let index = match seed {
            // `u64 % n` fits `usize`: `n` does.
            Some(seed) => (seed % n as u64) as usize,
            None => self.next_in_schedule % n,
        };
        self.next_in_schedule = (index + 1) % n;
        vec![schedule[index]]
    }

    fn set_context(&mut self, context: &[f64]) {
        self.field.outline = Outline::shared(context[0]);
    }

    fn sample_start(&self, rng: &mut ChaCha8Rng) -> Vector2<f64> {
        let (low, high) = (self.setup.workspace.min, self.setup.workspace.max);
        loop {
            let x = Vector2::new(
                rng.random_range(low.x..high.x),
                rng.random_range(low.y..high.y),
            );
            if x.norm() >= MIN_START_RADIUS {
                return x;
            }
        }
    }

    fn field(&self) -> &dyn VelocityField {
        &self.field
    }

    fn velocity_gain(&self) -> f64 {
        25.0
    }

    fn evaluate(&self, x: &Vector2<f64>, _xd: &Vector2<f64>, info: &mut Info) -> Outcome {
        let error = self.field.outline.distance(x);
        info.extend([
            ("outline_error".into(), error),
            (
                SUCCESS_INFO.into(),
                f64::from(u8::from(error < SUCCESS_DISTANCE)),
            ),
        ]);
        Outcome {
            reward: -error,
            terminated: false,
        }
    }

    fn draw(&self, canvas: &mut Canvas) {
        canvas.polyline(&self.field.outline.polyline(720), true, GREY, 2.0);
    }

    /// The outline the motion should trace for `context`.
    fn context_bodies(&self, context: &[f64]) -> Vec<Body> {
        let points = outline_curve(context)
            .iter()
            .map(|&[x, y]| planar(&Vector2::new(x, y)))
            .collect();
        let outline = Shape::Curve {
            points,
            closed: true,
            radius: 0.004,
        };
        vec![Body::new("outline", outline, GREY)]
    }
}
