//! `ciflow/Reach-v0` — any serial arm, given by its URDF, brings its tool to a goal.
//!
//! ## Description
//! The arm of the `urdf` argument (default: the shipped Franka Panda with its identified
//! dynamics, rotor inertia and limits) in the arm tasks' [`ArmEnv`] (the computed-torque
//! simulator, 1 ms physics, 10 ms control) moves its tool frame's origin to a goal position in its base
//! frame. Bring your own arm: any fixed-base chain of revolute, continuous, prismatic and
//! fixed joints, with joints locked, a tool link and rotor inertias given by the other
//! arguments.
//!
//! ## Action space
//! `Box(−q̈_max, q̈_max, (n,), float64)`: desired joint accelerations (rad/s², m/s² for a
//! prismatic joint) through the computed-torque layer, which applies the URDF's effort
//! limits. URDF carries no acceleration limits: for a URDF arm the box is unbounded.
//!
//! ## Observation space
//! `[q (n), q̇ (n), c (3)]` with the context `c = (x, y, z)`, the goal in the base frame (m).
//!
//! ## Context distribution
//! The goal is where the tool is at a posture drawn uniformly within [`GOAL_SPREAD`] rad
//! (or m) of the `home` posture on every joint (kept inside the joint limits), so every goal
//! is reachable. The context space is the box around [`GOAL_SAMPLES`] such goals drawn once
//! from a fixed seed, widened by [`CONTEXT_MARGIN`]; goals are drawn inside it.
//!
//! ## Expert
//! [`crate::expert::reach`]: the tool heads straight for the goal at up to 0.25 m/s,
//! resolved into joint accelerations by damped least squares with the redundancy pinned to
//! `home`.
//!
//! ## Rewards
//! `−‖tool − goal‖` (m) per step. `info`: `tool_x/y/z` (m), `distance_to_target` (m), `is_success`
//! (1 while the tool is within [`SUCCESS_RADIUS`] of the goal), `perturbed` (1 when a push
//! acted during the step), `time` (s).
//!
//! ## Starting state
//! `q = home + U(−s, s)ⁿ` (inside the limits) with `s = `[`START_SPREAD`], `q̇ = 0`;
//! `options.initial_position` / `initial_velocity` override them (within joint limits).
//! Option `push_force` (N, default 0) pushes the last link once per episode, as in
//! `ciflow/Pouring-v0`.
//!
//! ## Episode end
//! Truncated after 400 steps (4 s). Never terminated.
//!
//! ## Arguments
//! Texts (`gymnasium.make("ciflow/Reach-v0", urdf="arm.urdf", tool="tool0")`):
//! - `urdf`: the arm's URDF document, or the path of a file holding it (read where the
//!   argument is given: the environment's identity holds the document, not the path).
//! - `tool`: the tool link (default: the last link of the chain).
//! - `lock_joints`: joints held fixed, `NAME` (at 0) or `NAME=POSITION`, comma-separated.
//! - `armature`: the moving joints' reflected rotor inertias, comma-separated (default 0).
//! - `home`: the nominal posture, comma-separated (default: the Panda's home posture, or
//!   for a URDF arm the middle of each joint's range, 0 for a continuous joint).
//!
//! ## Version history
//! v0: initial version.

use std::collections::BTreeMap;
use std::sync::{Arc, LazyLock, Mutex};

use ciflow_engine::math::{DVector, Vector3};
use ciflow_engine::model::{ARMATURE, LockedJoint, ModelError};
use ciflow_engine::robot::{DynamicsError, PANDA_HOME, Robot, SerialChain, UrdfOptions, panda};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::arm_start::PUSH_FORCE_OPTION;
use crate::arm::{ArmEnv, ArmSetup, ArmTask};
use crate::env::{EnvError, Info, Outcome, SUCCESS_INFO};
use crate::expert::reach::expert_acceleration;
use crate::kwargs::{self, Kwargs, TextArgument};
use crate::planar::reject_unknown_options;
use crate::raster::{GREEN, RED, View, oblique_projection};
use crate::scene::{self, ARM_COLOR, Body, Shape};
use crate::shading::Camera;
use crate::space::{BoxSpace, Dtype};

pub const ID: &str = "ciflow/Reach-v0";
pub const URDF_ARGUMENT: &str = "urdf";
pub const TOOL_ARGUMENT: &str = "tool";
pub const LOCK_ARGUMENT: &str = "lock_joints";
pub const ARMATURE_ARGUMENT: &str = "armature";
pub const HOME_ARGUMENT: &str = "home";
/// The task's construction arguments, all texts.
pub const TEXT_ARGUMENTS: [TextArgument; 5] = [
    TextArgument {
        key: URDF_ARGUMENT,
        file: true,
    },
    TextArgument {
        key: TOOL_ARGUMENT,
        file: false,
    },
    TextArgument {
        key: LOCK_ARGUMENT,
        file: false,
    },
    TextArgument {
        key: ARMATURE_ARGUMENT,
        file: false,
    },
    TextArgument {
        key: HOME_ARGUMENT,
        file: false,
    },
];
/// Half-width of the postures about `home` whose tool positions are the goals, rad or m.
pub const GOAL_SPREAD: f64 = 0.5;
/// Goals drawn (seed 0) to place the context space.
pub const GOAL_SAMPLES: usize = 512;
/// How far the context space reaches past the sampled goals, m.
pub const CONTEXT_MARGIN: f64 = 0.02;
/// Half-width of the uniform start about `home`, rad or m.
pub const START_SPREAD: f64 = 0.05;
/// Distance to the goal that counts as reached, m.
pub const SUCCESS_RADIUS: f64 = 0.01;
const MAX_EPISODE_STEPS: u32 = 400;
/// Draws of a goal before giving up (one nearly always lands in the context space).
const GOAL_TRIES: usize = 1000;

/// The arm of the construction arguments and its nominal posture.
#[derive(Clone)]
pub struct Arm {
    pub robot: SerialChain,
    pub home: Vec<f64>,
}

/// A comma-separated list of finite numbers given as argument `name`.
fn numbers(name: &str, text: &str) -> Result<Vec<f64>, EnvError> {
    let invalid = |why: String| EnvError::InvalidOption {
        name: name.into(),
        detail: format!("`{text}`: {why}; comma-separated finite numbers are needed"),
    };
    let values = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| invalid(e.to_string()))?;
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(invalid(format!("value {i} is {}", values[i]))),
        None => Ok(values),
    }
}

/// The argument a URDF arm's construction failed on: the tool, the locked joints, the
/// armature, or else the document itself.
fn argument_at_fault(error: &ModelError) -> &'static str {
    match error {
        ModelError::NoSuchFrame(_) => TOOL_ARGUMENT,
        ModelError::Lock { .. } => LOCK_ARGUMENT,
        ModelError::InvalidArmature { .. } => ARMATURE_ARGUMENT,
        ModelError::Dimension { what, .. } if *what == ARMATURE => ARMATURE_ARGUMENT,
        _ => URDF_ARGUMENT,
    }
}

/// The arm the arguments describe (see the module docs).
pub fn arm(kwargs: &Kwargs) -> Result<Arm, EnvError> {
    let keys: Vec<_> = TEXT_ARGUMENTS.iter().map(|a| a.key).collect();
    reject_unknown_options(kwargs, &keys)?;
    let text = |name| kwargs::text(kwargs, name);
    let (robot, default_home): (SerialChain, Vec<f64>) = match text(URDF_ARGUMENT)? {
        None => {
            if let Some(name) = [TOOL_ARGUMENT, LOCK_ARGUMENT, ARMATURE_ARGUMENT]
                .into_iter()
                .find(|name| kwargs.contains_key(*name))
            {
                return Err(EnvError::InvalidOption {
                    name: name.into(),
                    detail: "applies to an arm given by `urdf` (the default Panda is complete)"
                        .into(),
                });
            }
            (panda(), PANDA_HOME.to_vec())
        }
        Some(urdf) => {
            let locked = match text(LOCK_ARGUMENT)? {
                None => vec![],
                Some(list) => list
                    .split(',')
                    .map(|joint| {
                        joint.trim().parse::<LockedJoint>().map_err(|detail| {
                            EnvError::InvalidOption {
                                name: LOCK_ARGUMENT.into(),
                                detail,
                            }
                        })
                    })
                    .collect::<Result<_, _>>()?,
            };
            let options = UrdfOptions {
                locked,
                tool: text(TOOL_ARGUMENT)?.map(str::to_owned),
                armature: text(ARMATURE_ARGUMENT)?
                    .map(|list| numbers(ARMATURE_ARGUMENT, list))
                    .transpose()?,
            };
            let chain =
                SerialChain::from_urdf(urdf, &options).map_err(|e| EnvError::InvalidOption {
                    name: argument_at_fault(&e).into(),
                    detail: e.to_string(),
                })?;
            if chain.dof() == 0 {
                // An arm that cannot move would "reach" with an empty action space.
                let (name, cause) = if options.locked.is_empty() {
                    (URDF_ARGUMENT, "the URDF has no movable joint")
                } else {
                    (LOCK_ARGUMENT, "every movable joint is locked")
                };
                return Err(EnvError::InvalidOption {
                    name: name.into(),
                    detail: format!("{cause}: a reach task needs an arm with at least one"),
                });
            }
            let limits = chain.limits();
            let middle = (0..chain.dof())
                .map(|i| {
                    let m = 0.5 * (limits.q_min[i] + limits.q_max[i]);
                    if m.is_finite() { m } else { 0.0 }
                })
                .collect();
            (chain, middle)
        }
    };
    let home = match text(HOME_ARGUMENT)? {
        None => default_home,
        Some(list) => numbers(HOME_ARGUMENT, list)?,
    };
    let limits = robot.limits();
    if home.len() != robot.dof() {
        return Err(EnvError::InvalidOption {
            name: HOME_ARGUMENT.into(),
            detail: format!("{} values for an arm of {} joints", home.len(), robot.dof()),
        });
    }
    if let Some(i) =
        (0..home.len()).find(|&i| !(limits.q_min[i]..=limits.q_max[i]).contains(&home[i]))
    {
        return Err(EnvError::InvalidOption {
            name: HOME_ARGUMENT.into(),
            detail: format!(
                "joint {i} = {} is outside its limits [{}, {}]",
                home[i], limits.q_min[i], limits.q_max[i]
            ),
        });
    }
    Ok(Arm { robot, home })
}

/// The arm [`Reach`] drives with these arguments (the registry's `robot`).
pub fn robot(kwargs: &Kwargs) -> Result<Box<dyn Robot>, EnvError> {
    Ok(Box::new(prototype(kwargs)?.arm.robot.clone()))
}

/// What every environment built with the same arguments shares: the parsed arm and the
/// context space its sampled goals span.
struct Prototype {
    arm: Arm,
    context_space: BoxSpace,
}

/// Prototypes by their arguments (as JSON), so that a session of many environments parses
/// its URDF and samples its goal box once, not once per environment.
static PROTOTYPES: LazyLock<Mutex<BTreeMap<String, Arc<Prototype>>>> =
    LazyLock::new(Default::default);
/// Argument sets remembered at once; past it the memory starts over.
const REMEMBERED_PROTOTYPES: usize = 16;

/// The prototype of `kwargs`, built on first use.
fn prototype(kwargs: &Kwargs) -> Result<Arc<Prototype>, EnvError> {
    // Arguments that do not serialise (none do today) are simply not remembered.
    let key = serde_json::to_string(&kwargs::to_json(kwargs)).ok();
    let known = PROTOTYPES.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(prototype) = key.as_ref().and_then(|key| known.get(key)) {
        return Ok(Arc::clone(prototype));
    }
    drop(known);
    let arm = arm(kwargs)?;
    let mut sampler = ChaCha8Rng::seed_from_u64(0);
    let mut low = Vector3::repeat(f64::INFINITY);
    let mut high = Vector3::repeat(f64::NEG_INFINITY);
    for _ in 0..GOAL_SAMPLES {
        let goal = sampled_goal(&arm.robot, &arm.home, &mut sampler)?;
        low = low.inf(&goal);
        high = high.sup(&goal);
    }
    let context_space = BoxSpace::new(
        (low.add_scalar(-CONTEXT_MARGIN)).as_slice().to_vec(),
        (high.add_scalar(CONTEXT_MARGIN)).as_slice().to_vec(),
        Dtype::Float64,
    );
    let built = Arc::new(Prototype { arm, context_space });
    if let Some(key) = key {
        let mut known = PROTOTYPES.lock().unwrap_or_else(|p| p.into_inner());
        if known.len() >= REMEMBERED_PROTOTYPES {
            known.clear();
        }
        known.insert(key, Arc::clone(&built));
    }
    Ok(built)
}

/// The reach task (see the module docs).
pub struct Reach {
    setup: ArmSetup,
    context_space: BoxSpace,
    home: Vec<f64>,
    goal: Vector3,
}

/// The reach environment on the arm the arguments describe.
pub fn make(kwargs: &Kwargs) -> Result<ArmEnv<Reach>, EnvError> {
    let prototype = prototype(kwargs)?;
    let context_space = prototype.context_space.clone();
    let task = Reach {
        setup: ArmSetup {
            id: ID,
            max_episode_steps: MAX_EPISODE_STEPS,
            trail: "tool_trail",
        },
        goal: Vector3::from_column_slice(&context_space.low),
        context_space,
        home: prototype.arm.home.clone(),
    };
    ArmEnv::with_robot(task, Box::new(prototype.arm.robot.clone()))
}

impl Reach {
    pub fn goal(&self) -> &Vector3 {
        &self.goal
    }
}

impl ArmEnv<Reach> {
    /// The tool frame's origin now, base frame.
    pub fn tool(&self) -> Result<Vector3, EnvError> {
        self.pose()
    }

    pub fn goal(&self) -> &Vector3 {
        self.task().goal()
    }
}

fn tool_position(robot: &dyn Robot, q: &[f64]) -> Result<Vector3, EnvError> {
    robot
        .frame_placement(q, robot.end_effector())
        .map(|placement| placement.translation.vector)
        .map_err(|e| EnvError::Simulation(e.into()))
}

/// `home + U(−spread, spread)ⁿ`, kept inside the joint limits.
fn posture_near(robot: &dyn Robot, home: &[f64], spread: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let limits = robot.limits();
    home.iter()
        .enumerate()
        .map(|(i, h)| {
            let q = h + rng.random_range(-spread..=spread);
            q.clamp(limits.q_min[i], limits.q_max[i])
        })
        .collect()
}

/// The tool's position at a posture drawn within [`GOAL_SPREAD`] of `home`.
fn sampled_goal(
    robot: &dyn Robot,
    home: &[f64],
    rng: &mut ChaCha8Rng,
) -> Result<Vector3, EnvError> {
    tool_position(robot, &posture_near(robot, home, GOAL_SPREAD, rng))
}

impl ArmTask for Reach {
    type Pose = Vector3;

    fn setup(&self) -> &ArmSetup {
        &self.setup
    }

    fn context_space(&self) -> &BoxSpace {
        &self.context_space
    }

    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError> {
        reject_unknown_options(extra, &[PUSH_FORCE_OPTION])
    }

    fn sample_context(
        &self,
        robot: &dyn Robot,
        rng: &mut ChaCha8Rng,
    ) -> Result<Vec<f64>, EnvError> {
        let inside = (0..GOAL_TRIES)
            .map(|_| sampled_goal(robot, &self.home, rng))
            .find(|goal| {
                goal.as_ref()
                    .map_or(true, |g| self.context_space.contains(g.as_slice()))
            })
            .ok_or_else(|| EnvError::OutOfBounds {
                what: "context",
                detail: format!("no goal of {GOAL_TRIES} draws fell in the context space"),
            })??;
        Ok(inside.as_slice().to_vec())
    }

    fn sample_start(&self, robot: &dyn Robot, rng: &mut ChaCha8Rng) -> Vec<f64> {
        posture_near(robot, &self.home, START_SPREAD, rng)
    }

    fn set_context(&mut self, context: &[f64]) {
        self.goal = Vector3::from_column_slice(context);
    }

    fn pose(&self, robot: &dyn Robot, q: &[f64]) -> Result<Vector3, EnvError> {
        tool_position(robot, q)
    }

    fn traced_point(tool: &Vector3) -> Vector3 {
        *tool
    }

    fn evaluate(&self, tool: &Vector3, info: &mut Info) -> Outcome {
        let distance = (tool - self.goal).norm();
        info.extend([
            ("tool_x".into(), tool.x),
            ("tool_y".into(), tool.y),
            ("tool_z".into(), tool.z),
            ("distance_to_target".into(), distance),
            (
                SUCCESS_INFO.into(),
                f64::from(u8::from(distance < SUCCESS_RADIUS)),
            ),
        ]);
        Outcome {
            reward: -distance,
            terminated: false,
        }
    }

    fn expert_acceleration(
        &self,
        robot: &dyn Robot,
        q: &[f64],
        qd: &[f64],
    ) -> Result<DVector, DynamicsError> {
        expert_acceleration(robot, &self.goal, &self.home, q, qd)
    }

    /// The arm as capsules between its joint origins, the tool and the goal.
    fn bodies(&self, robot: &dyn Robot, q: &[f64], goal: &[f64]) -> Result<Vec<Body>, EnvError> {
        let tool = Shape::sphere(tool_position(robot, q)?, 0.015);
        let goal = Shape::sphere(Vector3::from_column_slice(goal), 0.02);
        let mut bodies = scene::arm_links(robot, q, LINK_RADIUS, ARM_COLOR)?;
        bodies.extend([Body::new("tool", tool, RED), Body::new("goal", goal, GREEN)]);
        Ok(bodies)
    }

    /// Obliquely from the front right, framing the base and every goal of the context
    /// space.
    fn camera(&self) -> Camera {
        let project = |p: &Vector3| oblique_projection(p, CAMERA_AZIMUTH, CAMERA_ELEVATION);
        let context_box = &self.context_space;
        let corners = (0..8).map(|k| {
            Vector3::from_fn(|i, _| {
                if k >> i & 1 == 0 {
                    context_box.low[i]
                } else {
                    context_box.high[i]
                }
            })
        });
        let mut view = View {
            min: project(&Vector3::zeros()),
            max: project(&Vector3::zeros()),
        };
        for corner in corners {
            let p = project(&corner);
            view.min = view.min.inf(&p);
            view.max = view.max.sup(&p);
        }
        let pad = 0.15 * (view.max - view.min).max();
        view.min.add_scalar_mut(-pad);
        view.max.add_scalar_mut(pad);
        Camera {
            azimuth: CAMERA_AZIMUTH,
            elevation: CAMERA_ELEVATION,
            view,
        }
    }
}

/// Radius of the capsules drawn for the arm's links, m.
const LINK_RADIUS: f64 = 0.04;
/// Azimuth of the camera, rad: it stands at the robot's front right.
const CAMERA_AZIMUTH: f64 = -0.6;
/// Elevation of the camera above the horizon, rad (20°).
const CAMERA_ELEVATION: f64 = 0.35;
