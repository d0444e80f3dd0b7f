//! `ciflow/Reach-v0` — any serial arm, given by its URDF, brings its tool to a goal.
//!
//! ## Description
//! The arm of the `urdf` argument (default: the shipped Franka Panda with its identified
//! dynamics, rotor inertia and limits) under the computed-torque [`Simulator`] (1 ms
//! physics, 10 ms control) moves its tool frame's origin to a goal position in its base
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

use ciflow_engine::math::Vector3;
use ciflow_engine::model::LockedJoint;
use ciflow_engine::robot::{PANDA_HOME, Robot, SerialChain, UrdfOptions, panda};
use ciflow_engine::sim::{Perturbation, SimConfig, Simulator};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::arm_start::{self, PUSH_FORCE_OPTION};
use crate::env::{
    Env, EnvError, EnvSpec, Info, PERTURBED_INFO, Phase, ResetOptions, SUCCESS_INFO, Step,
};
use crate::expert::reach::expert_acceleration;
use crate::kwargs::{self, Kwargs, TextArgument};
use crate::planar::reject_unknown_options;
use crate::raster::{GREEN, RED, View, oblique_projection};
use crate::scene::{self, ARM_COLOR, Body, Scene, Shape};
use crate::seeding::EpisodeRng;
use crate::shading::{self, Camera, Picture};
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

/// A comma-separated list of numbers given as argument `name`.
fn numbers(name: &str, text: &str) -> Result<Vec<f64>, EnvError> {
    text.split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| EnvError::InvalidOption {
            name: name.into(),
            detail: format!("`{text}`: {e}; comma-separated numbers are needed"),
        })
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
                    name: URDF_ARGUMENT.into(),
                    detail: e.to_string(),
                })?;
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
            detail: format!("joint {i} = {} is outside its limits", home[i]),
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

/// The reach environment (see the module docs).
pub struct Reach {
    spec: Arc<EnvSpec>,
    simulator: Simulator,
    home: Vec<f64>,
    rng: EpisodeRng,
    goal: Vector3,
    phase: Phase,
    steps: u32,
    tool_trail: Vec<Vector3>,
}

impl Reach {
    pub fn new(kwargs: &Kwargs) -> Result<Self, EnvError> {
        let prototype = prototype(kwargs)?;
        let (robot, home) = (prototype.arm.robot.clone(), prototype.arm.home.clone());
        let context_space = prototype.context_space.clone();
        let limits = robot.limits().clone();
        let n = robot.dof();
        let config = SimConfig {
            physics_dt: 0.001,
            control_dt: 0.01,
            ..SimConfig::default()
        };
        // Velocities can exceed their nominal limits under pushes.
        let observation_space = BoxSpace::new(
            [
                limits.q_min.as_slice(),
                &vec![f64::NEG_INFINITY; n],
                &context_space.low,
            ]
            .concat(),
            [
                limits.q_max.as_slice(),
                &vec![f64::INFINITY; n],
                &context_space.high,
            ]
            .concat(),
            Dtype::Float64,
        );
        let spec = EnvSpec {
            id: ID.into(),
            observation_space,
            action_space: BoxSpace::new(
                (-&limits.qdd_max).as_slice().to_vec(),
                limits.qdd_max.as_slice().to_vec(),
                Dtype::Float64,
            ),
            context_space,
            control_dt: config.control_dt,
            physics_dt: config.physics_dt,
            max_episode_steps: MAX_EPISODE_STEPS,
        }
        .shared();
        let simulator = Simulator::new(Box::new(robot), config).map_err(EnvError::Simulation)?;
        let goal = Vector3::from_column_slice(&spec.context_space.low);
        Ok(Self {
            spec,
            simulator,
            home,
            rng: EpisodeRng::default(),
            goal,
            phase: Phase::NeedsReset,
            steps: 0,
            tool_trail: vec![],
        })
    }

    fn robot(&self) -> &dyn Robot {
        self.simulator.robot()
    }

    /// The tool frame's origin now, base frame.
    pub fn tool(&self) -> Result<Vector3, EnvError> {
        tool_position(self.robot(), self.simulator.q().as_slice())
    }

    pub fn goal(&self) -> &Vector3 {
        &self.goal
    }

    fn observation(&self) -> Vec<f64> {
        [
            self.simulator.q().as_slice(),
            self.simulator.qd().as_slice(),
            self.goal.as_slice(),
        ]
        .concat()
    }

    fn outcome(&self) -> Result<(f64, Info), EnvError> {
        let tool = self.tool()?;
        let distance = (tool - self.goal).norm();
        let info = Info::from([
            ("tool_x".into(), tool.x),
            ("tool_y".into(), tool.y),
            ("tool_z".into(), tool.z),
            ("distance_to_target".into(), distance),
            (
                SUCCESS_INFO.into(),
                f64::from(u8::from(distance < SUCCESS_RADIUS)),
            ),
            (
                PERTURBED_INFO.into(),
                f64::from(u8::from(self.simulator.perturbed())),
            ),
            ("time".into(), self.simulator.time()),
        ]);
        Ok((-distance, info))
    }

    fn apply_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.spec.context_space.check("context", context)?;
        self.goal = Vector3::from_column_slice(context);
        Ok(())
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

impl Env for Reach {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(
        &mut self,
        seed: Option<u64>,
        options: &ResetOptions,
    ) -> Result<(Vec<f64>, Info), EnvError> {
        reject_unknown_options(&options.extra, &[PUSH_FORCE_OPTION])?;
        let push_force = arm_start::push_force(&options.extra)?;
        let robot = self.simulator.robot();
        let rng = self.rng.reseed(seed);
        let context = match &options.context {
            Some(context) => context.clone(),
            None => {
                let space = &self.spec.context_space;
                let inside = (0..GOAL_TRIES)
                    .map(|_| sampled_goal(robot, &self.home, rng))
                    .find(|goal| goal.as_ref().map_or(true, |g| space.contains(g.as_slice())))
                    .ok_or_else(|| EnvError::OutOfBounds {
                        what: "context",
                        detail: format!("no goal of {GOAL_TRIES} draws fell in the context space"),
                    })??;
                inside.as_slice().to_vec()
            }
        };
        let q0 = match &options.initial_position {
            Some(q0) => arm_start::initial_position(q0, robot.limits())?,
            None => posture_near(robot, &self.home, START_SPREAD, rng),
        };
        let joints = robot.dof();
        let qd0 = match &options.initial_velocity {
            Some(qd0) => arm_start::joint_vector("initial_velocity", qd0, joints)?,
            None => vec![0.0; joints],
        };
        // Drawn after the start, so a pushed episode starts where the unpushed one does.
        let push = arm_start::demo_push(self.rng.reseed(None), push_force, joints - 1);
        self.apply_context(&context)?;
        self.simulator
            .reset(&q0, &qd0)
            .map_err(EnvError::Simulation)?;
        if let Some(push) = push {
            self.simulator
                .perturb(push)
                .map_err(EnvError::InvalidPerturbation)?;
        }
        self.phase = Phase::Running;
        self.steps = 0;
        self.tool_trail = vec![self.tool()?];
        Ok((self.observation(), self.outcome()?.1))
    }

    fn step(&mut self, action: &[f64]) -> Result<Step, EnvError> {
        self.phase.running()?;
        self.spec.action_space.check("action", action)?;
        self.simulator.step(action).map_err(EnvError::Simulation)?;
        self.steps += 1;
        self.tool_trail.push(self.tool()?);
        let (reward, info) = self.outcome()?;
        let truncated = self.steps >= self.spec.max_episode_steps;
        if truncated {
            self.phase = Phase::Ended;
        }
        Ok(Step {
            observation: self.observation(),
            reward,
            terminated: false,
            truncated,
            info,
        })
    }

    fn expert_action(&self) -> Result<Vec<f64>, EnvError> {
        self.phase.started()?;
        let qdd = expert_acceleration(
            self.robot(),
            &self.goal,
            &self.home,
            self.simulator.q().as_slice(),
            self.simulator.qd().as_slice(),
        )
        .map_err(|e| EnvError::Simulation(e.into()))?;
        Ok(self.spec.action_space.clip(qdd.as_slice()))
    }

    fn set_context(&mut self, context: &[f64]) -> Result<(), EnvError> {
        self.phase.started()?;
        self.apply_context(context)
    }

    fn perturb(&mut self, perturbation: Perturbation) -> Result<(), EnvError> {
        self.phase.started()?;
        self.simulator
            .perturb(perturbation)
            .map_err(EnvError::InvalidPerturbation)
    }

    fn render(&self, width: u32, height: u32) -> Result<Vec<u8>, EnvError> {
        Ok(self.picture(width, height)?.into_pixels())
    }

    /// The arm as capsules between its joint origins, the tool and the goal.
    fn scene(&self, observation: &[f64]) -> Result<Scene, EnvError> {
        let (state, goal) = self.spec.split_observation(observation)?;
        let q = &state[..self.robot().dof()];
        let tool = Shape::sphere(tool_position(self.robot(), q)?, 0.015);
        let goal = Shape::sphere(Vector3::from_column_slice(goal), 0.02);
        let mut bodies = scene::arm_links(self.robot(), q, LINK_RADIUS, ARM_COLOR)?;
        bodies.extend([Body::new("tool", tool, RED), Body::new("goal", goal, GREEN)]);
        Ok(Scene { bodies })
    }
}

impl Reach {
    /// The shaded picture `render` returns, with which body each pixel shows: the
    /// [`Env::scene`] of the current observation and the tool's trail, seen obliquely from
    /// the front right, framing the base and every goal of the context space (blank
    /// before the first reset).
    pub fn picture(&self, width: u32, height: u32) -> Result<Picture, EnvError> {
        let project = |p: &Vector3| oblique_projection(p, CAMERA_AZIMUTH, CAMERA_ELEVATION);
        let context_box = &self.spec.context_space;
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
        let camera = Camera {
            azimuth: CAMERA_AZIMUTH,
            elevation: CAMERA_ELEVATION,
            view,
        };
        let mut scene = Scene::default();
        if self.phase != Phase::NeedsReset {
            scene = self.scene(&self.observation())?;
            scene
                .bodies
                .push(scene::trail("tool_trail", &self.tool_trail));
        }
        shading::render(&scene, &camera, width, height)
    }
}

/// Radius of the capsules drawn for the arm's links, m.
const LINK_RADIUS: f64 = 0.04;
/// Azimuth of the camera, rad: it stands at the robot's front right.
const CAMERA_AZIMUTH: f64 = -0.6;
/// Elevation of the camera above the horizon, rad (20°).
const CAMERA_ELEVATION: f64 = 0.35;
