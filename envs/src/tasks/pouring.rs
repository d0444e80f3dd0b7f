//! `ciflow/Pouring-v0` — the Franka Panda pours from a cup into a pot.
//!
//! ## Description
//! The 7-DOF Panda with its identified dynamics and its motors' reflected rotor inertia
//! (the engine's [`panda`] in the arm tasks' [`ArmEnv`]: the computed-torque simulator,
//! 1 ms physics, 10 ms control) holds a cup. The rotor inertia is what makes a push on the hand move the arm
//! rather than spin the light wrist and tip the cup (see `PANDA_ARMATURE`). A pot stands
//! at a 6-D pose; its rim has a lip on one side (local `−x`), and water must be poured
//! over the lip: the cup has to reach a pre-pour pose above the lip upright, then tilt
//! toward the pot's centre. Tilting anywhere else spills.
//!
//! ## Action space
//! `Box(−q̈_max, q̈_max, (7,), float64)`: desired joint accelerations (rad/s²), Franka's
//! limits `q̈_max = (15, 7.5, 10, 12.5, 15, 20, 20)`, through the computed-torque layer
//! (which also applies the torque and torque-rate limits). Out-of-range actions are refused.
//!
//! ## Observation space
//! `[q (7, rad), q̇ (7, rad/s), c (6)]` with the context
//! `c = (x, y, z, roll, pitch, yaw)` of the pot: position of its base centre in the
//! robot's base frame (m) and orientation `R = R_z(yaw) R_y(pitch) R_x(roll)` (rad).
//!
//! ## Context distribution
//! `x ∈ [0.42, 0.6]`, `y ∈ [−0.25, 0.25]`, `z ∈ [0, 0.1]`, `roll, pitch ∈ [−0.1, 0.1]`,
//! `yaw ∈ [−0.6, 0.6]`, uniform (the context space is this box).
//!
//! ## Expert
//! [`crate::expert::pouring`]: resolved-acceleration control of the spout toward the pour
//! point (6 cm above the lip) with the cup upright until 5 cm away, then tilted by
//! 1.45 rad toward the pot's centre; redundancy resolved toward a nominal posture.
//!
//! ## Rewards
//! `−‖spout − p*‖` (m) per step, `−100` on a spill. `info`: `spout_x/y/z` (m), `tilt`
//! (rad), `pour_distance` (m), `over_pot` (0/1), `spill` (0/1), `is_success` (1 while
//! pouring: tilt ≥ [`POURING_TILT`] with the spout over the pot's opening), `perturbed`
//! (1 when a push acted during the step: from the next step on, the arm moves under the
//! expert's command alone, from wherever the push left it), `time` (s).
//!
//! ## Starting state
//! `q = PANDA_HOME + U(−s, s)⁷` with the spread `s = 0.05` rad, `q̇ = 0`; the cup is
//! upright above the table. Option `start_spread` sets `s` (0 to [`MAX_START_SPREAD`]):
//! demonstrations from wider starts show how the expert returns to its path from states a
//! push would reach. `options.initial_position` / `initial_velocity` override them
//! (within joint limits).
//!
//! Option `push_force` (N, default 0) pushes the hand once per episode: a horizontal
//! force of magnitude `U(0, push_force)` in a uniform direction for [`DEMO_PUSH_DURATION`],
//! starting at `U(`[`DEMO_PUSH_WINDOW`]`)` s, drawn from the episode's seed. Expert
//! demonstrations recorded with it show how the expert recovers from pushes (noise
//! injection in the spirit of DART), the states a pushed policy has to handle; the
//! experiments record theirs with 40 N (`scripts/demo.py`), without which the flow, like
//! the expert heading straight for the pour point, rejoins its path only near the goal.
//!
//! ## Episode end
//! Terminated on a spill: tilt ≥ [`SPILL_TILT`] with the spout not over the opening.
//! Truncated after 600 steps (6 s).
//!
//! ## Arguments
//! None.
//!
//! ## Version history
//! v0: initial version.

use std::collections::BTreeMap;

use ciflow_engine::math::{DVector, Isometry3, Vector3};
use ciflow_engine::robot::{DynamicsError, PANDA_HOME, Robot, panda};
use nalgebra::{Translation3, UnitQuaternion, Vector2};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::arm::{ArmEnv, ArmSetup, ArmTask};
use crate::env::{EnvError, Info, Outcome, SUCCESS_INFO};
use crate::expert::pouring::{CUP_RADIUS, CupPose, PourTarget, expert_acceleration};
use crate::planar::reject_unknown_options;
use crate::raster::{BLACK, BLUE, ORANGE, RED, Rgb, View};
use crate::scene::{self, ARM_COLOR, Body, Shape, cylinder_between};
use crate::shading::Camera;
use crate::space::{BoxSpace, Dtype};

pub const ID: &str = "ciflow/Pouring-v0";
/// The pot: a cylinder of this radius and height, m.
pub const POT_RADIUS: f64 = 0.08;
pub const POT_HEIGHT: f64 = 0.12;
/// The lip: distance from the pot's axis (on its local `−x` side), m.
pub const LIP_OFFSET: f64 = 0.045;
/// Height of the pour point above the lip, m.
pub const POUR_CLEARANCE: f64 = 0.06;
/// Tilt beyond which water leaves the cup, rad.
pub const SPILL_TILT: f64 = 0.5;
/// Tilt that counts as pouring, rad.
pub const POURING_TILT: f64 = 1.2;
pub const SPILL_REWARD: f64 = -100.0;
/// Default half-width of the uniform start around `PANDA_HOME`, rad.
pub const START_SPREAD: f64 = 0.05;
/// Widest `start_spread` option: keeps every start within the Panda's joint limits, rad.
pub const MAX_START_SPREAD: f64 = 0.3;
pub const START_SPREAD_OPTION: &str = "start_spread";
pub use super::arm_start::{DEMO_PUSH_DURATION, DEMO_PUSH_WINDOW, PUSH_FORCE_OPTION};
const CONTEXT_LOW: [f64; 6] = [0.42, -0.25, 0.0, -0.1, -0.1, -0.6];
const CONTEXT_HIGH: [f64; 6] = [0.6, 0.25, 0.1, 0.1, 0.1, 0.6];
const DOF: usize = 7;
/// The hand, the last of the Panda's movable links: where pushes act (the demonstrations'
/// and the evaluation's).
pub const HAND_LINK: usize = DOF - 1;

/// The pot's pose from a context `(x, y, z, roll, pitch, yaw)`.
pub fn pot_pose(context: &[f64]) -> Isometry3 {
    Isometry3::from_parts(
        Translation3::new(context[0], context[1], context[2]),
        UnitQuaternion::from_euler_angles(context[3], context[4], context[5]),
    )
}

/// Where and which way to pour into the pot at `pot`.
pub fn pour_target(pot: &Isometry3) -> PourTarget {
    let lip = pot * nalgebra::Point3::new(-LIP_OFFSET, 0.0, POT_HEIGHT);
    let inward = pot.rotation * Vector3::x();
    PourTarget {
        point: lip.coords + POUR_CLEARANCE * Vector3::z(),
        direction: Vector3::new(inward.x, inward.y, 0.0).normalize(),
    }
}

/// Whether `point` lies above the pot's opening (within its radius, horizontally).
fn over_opening(pot: &Isometry3, point: &Vector3) -> bool {
    let opening = pot * nalgebra::Point3::new(0.0, 0.0, POT_HEIGHT);
    let horizontal = Vector2::new(point.x - opening.x, point.y - opening.y);
    horizontal.norm() < POT_RADIUS && point.z > opening.z
}

/// The pouring task (see the module docs).
pub struct Pouring {
    setup: ArmSetup,
    context_space: BoxSpace,
    /// Half-width of the start about [`PANDA_HOME`] for the episode being reset, rad.
    start_spread: f64,
    pot: Isometry3,
    target: PourTarget,
}

/// The arm this task drives: the Panda with its rotor inertia and real limits.
pub fn robot() -> Box<dyn Robot> {
    Box::new(panda())
}

/// The pouring environment.
pub fn make() -> Result<ArmEnv<Pouring>, EnvError> {
    ArmEnv::with_robot(Pouring::new(), robot())
}

impl Pouring {
    pub fn new() -> Self {
        let context_space =
            BoxSpace::new(CONTEXT_LOW.to_vec(), CONTEXT_HIGH.to_vec(), Dtype::Float64);
        // Until the first reset sets a context, the pot stands in the middle of the box.
        let middle: Vec<f64> = CONTEXT_LOW
            .iter()
            .zip(&CONTEXT_HIGH)
            .map(|(l, h)| (l + h) / 2.0)
            .collect();
        let pot = pot_pose(&middle);
        Self {
            setup: ArmSetup {
                id: ID,
                max_episode_steps: 600,
                trail: "spout_trail",
            },
            context_space,
            start_spread: START_SPREAD,
            target: pour_target(&pot),
            pot,
        }
    }

    pub fn pour_target(&self) -> &PourTarget {
        &self.target
    }
}

impl Default for Pouring {
    fn default() -> Self {
        Self::new()
    }
}

impl ArmEnv<Pouring> {
    /// The cup now.
    pub fn cup(&self) -> Result<CupPose, EnvError> {
        self.pose()
    }

    pub fn pour_target(&self) -> &PourTarget {
        self.task().pour_target()
    }
}

impl ArmTask for Pouring {
    type Pose = CupPose;

    fn setup(&self) -> &ArmSetup {
        &self.setup
    }

    fn context_space(&self) -> &BoxSpace {
        &self.context_space
    }

    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError> {
        reject_unknown_options(extra, &[START_SPREAD_OPTION, PUSH_FORCE_OPTION])?;
        self.start_spread = match extra.get(START_SPREAD_OPTION).copied() {
            None => START_SPREAD,
            Some(s) if (0.0..=MAX_START_SPREAD).contains(&s) => s,
            Some(s) => {
                return Err(EnvError::InvalidOption {
                    name: START_SPREAD_OPTION.into(),
                    detail: format!("{s} rad; 0 to {MAX_START_SPREAD} are supported"),
                });
            }
        };
        Ok(())
    }

    fn sample_context(&self, _: &dyn Robot, rng: &mut ChaCha8Rng) -> Result<Vec<f64>, EnvError> {
        Ok(CONTEXT_LOW
            .iter()
            .zip(&CONTEXT_HIGH)
            .map(|(l, h)| rng.random_range(*l..=*h))
            .collect())
    }

    fn sample_start(&self, _: &dyn Robot, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let spread = self.start_spread;
        PANDA_HOME
            .iter()
            .map(|q| q + rng.random_range(-spread..=spread))
            .collect()
    }

    fn set_context(&mut self, context: &[f64]) {
        self.pot = pot_pose(context);
        self.target = pour_target(&self.pot);
    }

    fn pose(&self, robot: &dyn Robot, q: &[f64]) -> Result<CupPose, EnvError> {
        let hand = robot
            .frame_placement(q, robot.end_effector())
            .map_err(|e| EnvError::Simulation(e.into()))?;
        Ok(CupPose::of_hand(&hand))
    }

    fn traced_point(cup: &CupPose) -> Vector3 {
        cup.spout
    }

    fn evaluate(&self, cup: &CupPose, info: &mut Info) -> Outcome {
        let tilt = cup.tilt();
        let distance = (cup.spout - self.target.point).norm();
        let over = over_opening(&self.pot, &cup.spout);
        let spill = tilt >= SPILL_TILT && !over;
        let success = tilt >= POURING_TILT && over;
        let flag = |b: bool| f64::from(u8::from(b));
        info.extend([
            ("spout_x".into(), cup.spout.x),
            ("spout_y".into(), cup.spout.y),
            ("spout_z".into(), cup.spout.z),
            ("tilt".into(), tilt),
            ("pour_distance".into(), distance),
            ("over_pot".into(), flag(over)),
            ("spill".into(), flag(spill)),
            (SUCCESS_INFO.into(), flag(success)),
        ]);
        Outcome {
            reward: if spill { SPILL_REWARD } else { -distance },
            terminated: spill,
        }
    }

    fn expert_acceleration(
        &self,
        robot: &dyn Robot,
        q: &[f64],
        qd: &[f64],
    ) -> Result<DVector, DynamicsError> {
        expert_acceleration(robot, &self.target, &PANDA_HOME, q, qd)
    }

    /// The table, the arm as capsules, the cup in its fingers and the pot with its lip.
    fn bodies(&self, robot: &dyn Robot, q: &[f64], context: &[f64]) -> Result<Vec<Body>, EnvError> {
        let hand = robot
            .frame_placement(q, robot.end_effector())
            .map_err(|e| EnvError::Simulation(e.into()))?;
        let cup = CupPose::of_hand(&hand);
        let pot = pot_pose(context);
        let lip = pot * nalgebra::Point3::new(-LIP_OFFSET, 0.0, POT_HEIGHT);
        let mut bodies = vec![scene::table((-0.3, 0.85), (-0.5, 0.5), 0.02, TABLE)];
        bodies.extend(scene::arm_links(robot, q, 0.045, ARM_COLOR)?);
        let fingers = Shape::Capsule {
            from: hand.translation.vector,
            to: (cup.bottom + cup.top) / 2.0,
            radius: 0.012,
        };
        bodies.extend([
            Body::new("robot/fingers", fingers, BLACK),
            Body::new(
                "cup",
                cylinder_between(&cup.bottom, &cup.top, CUP_RADIUS),
                BLUE,
            ),
            Body::new("spout", Shape::sphere(cup.spout, 0.01), RED),
            Body::new(
                "pot",
                Shape::Cylinder {
                    pose: pot,
                    radius: POT_RADIUS,
                    height: POT_HEIGHT,
                },
                ORANGE,
            ),
            Body::new("lip", Shape::sphere(lip.coords, 0.012), RED),
        ]);
        Ok(bodies)
    }

    fn camera(&self) -> Camera {
        CAMERA
    }
}

/// The camera of `render`: at the robot's front right (azimuth −0.6 rad), 20° above the
/// horizon, showing the table, the arm over its workspace and the pot.
const CAMERA: Camera = Camera {
    azimuth: -0.6,
    elevation: 0.35,
    view: View {
        min: Vector2::new(-0.35, -0.3),
        max: Vector2::new(0.7, 0.75),
    },
};
/// The table's colour.
const TABLE: Rgb = [205, 200, 190];
