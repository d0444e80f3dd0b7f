//! `ciflow/Obstacle-v0` — reach a target among circular obstacles.
//!
//! ## Description
//! A 1 kg point mass in the plane must reach a target while keeping out of 1–3 circular
//! obstacles (radius [`OBSTACLE_RADIUS`]). The context holds the obstacles' centres and
//! the target, so the motion must be conditioned on a 4-, 6- or 8-dimensional context,
//! as in the paper's second experiment.
//!
//! ## Action space
//! `Box(-20, 20, (2,), float64)`: desired acceleration `ẍ_des` (m/s²) through the
//! computed-torque layer; out-of-range actions are refused with `OutOfBounds`.
//!
//! ## Observation space
//! `[x, y, ẋ, ẏ, o₁ₓ, o₁ᵧ, …, g_x, g_y]`: position (m), velocity (m/s), obstacle
//! centres (m), target (m).
//!
//! ## Context distribution
//! Obstacle centres uniform in `[−0.45, 0.45] × [−0.7, 0.7]`, target uniform in
//! `[0.55, 0.95] × [−0.6, 0.6]`, rejected until the safety discs (radius
//! [`SAFETY_RADIUS`]) are 5 cm apart from each other and from the target. A context given
//! in the options must keep the safety discs disjoint and the target outside them.
//!
//! ## Expert
//! [`ModulatedField`]: a saturated linear attractor (2 /s, 0.6 m/s) deflected by
//! modulation matrices around the safety discs (reactivity [`EXPERT_REACTIVITY`]),
//! continuous in state and context; tracked with `k_v = 20 /s`, clipped to the action
//! space. It never enters the obstacles.
//!
//! ## Rewards
//! `−‖x − g‖` per step (m); `−100` on collision. `info`: `distance_to_target` (m),
//! `collision` (0/1), `is_success` (0/1), `time` (s).
//!
//! ## Starting state
//! Position uniform in `[−0.95, −0.65] × [−0.6, 0.6]`, outside the safety discs; zero
//! velocity. `options.initial_position` / `initial_velocity` override them (a start
//! inside an obstacle is refused).
//!
//! ## Episode end
//! Terminated on reaching the target (within 2 cm, slower than 5 cm/s: success) or on
//! entering an obstacle (collision). Truncated after 800 steps (8 s).
//!
//! ## Arguments
//! `obstacles` (1, 2 or 3; default 3): the number of obstacles. Reset options may repeat
//! it but not change it, since it sets the observation space.
//!
//! ## Version history
//! v0: initial version.

use std::collections::BTreeMap;

use nalgebra::{Vector2, Vector3};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::env::{EnvError, Info, Outcome, SUCCESS_INFO};
use crate::expert::modulation::{Disc, ModulatedField};
use crate::expert::tracking::VelocityField;
use crate::planar::{PlanarEnv, PlanarSetup, PlanarTask, reject_unknown_options};
use crate::raster::{Canvas, GREEN, GREY, LIGHT_GREY, View};
use crate::scene::{Body, Shape, cylinder_between, planar};
use crate::space::{BoxSpace, Dtype};

pub const ID: &str = "ciflow/Obstacle-v0";
/// Radius of an obstacle's body: entering it is a collision, m.
pub const OBSTACLE_RADIUS: f64 = 0.1;
/// Radius of the disc the expert keeps out of, m.
pub const SAFETY_RADIUS: f64 = 0.16;
/// Distance and speed under which the target counts as reached, m and m/s.
pub const SUCCESS_DISTANCE: f64 = 0.02;
pub const SUCCESS_SPEED: f64 = 0.05;
pub const COLLISION_REWARD: f64 = -100.0;
/// The expert's reactivity `ρ` ([`crate::expert::modulation`]). With `ρ = 1` the expert
/// runs straight at an obstacle and turns within centimetres of its safety disc; `ρ = 3`
/// bends the path from about two radii out (`Γ^{−1/3}` is still 0.46 at `Γ = 10`), but
/// did not raise the generic network's success (`--contraction-layers 0`, 3 obstacles,
/// 1000 demonstrations, 2 epochs: 69% of 100 held-out contexts with `ρ = 3`, 65% with
/// `ρ = 2`, against 70% with `ρ = 1`), so the expert keeps `ρ = 1`.
pub const EXPERT_REACTIVITY: f64 = 1.0;
/// Gap kept between sampled safety discs, targets and starts, m.
const CLEARANCE: f64 = 0.05;
pub const OBSTACLES_OPTION: &str = "obstacles";
pub const MAX_OBSTACLES: usize = 3;

const OBSTACLE_REGION: (Vector2<f64>, Vector2<f64>) =
    (Vector2::new(-0.45, -0.7), Vector2::new(0.45, 0.7));
const TARGET_REGION: (Vector2<f64>, Vector2<f64>) =
    (Vector2::new(0.55, -0.6), Vector2::new(0.95, 0.6));
const START_REGION: (Vector2<f64>, Vector2<f64>) =
    (Vector2::new(-0.95, -0.6), Vector2::new(-0.65, 0.6));

/// The obstacle-avoidance task (see the module docs).
pub struct ObstacleAvoidance {
    setup: PlanarSetup,
    obstacles: usize,
    context_space: BoxSpace,
    field: ModulatedField,
}

/// The environment with `obstacles` obstacles (1 to 3).
pub fn make(obstacles: usize) -> Result<PlanarEnv<ObstacleAvoidance>, EnvError> {
    PlanarEnv::new(ObstacleAvoidance::new(obstacles)?)
}

fn uniform(rng: &mut ChaCha8Rng, (low, high): (Vector2<f64>, Vector2<f64>)) -> Vector2<f64> {
    Vector2::new(
        rng.random_range(low.x..high.x),
        rng.random_range(low.y..high.y),
    )
}

/// Splits a context into obstacle centres and the target.
fn parse_context(context: &[f64]) -> (Vec<Vector2<f64>>, Vector2<f64>) {
    let (obstacles, target) = context.split_at(context.len() - 2);
    (
        obstacles
            .chunks(2)
            .map(|c| Vector2::new(c[0], c[1]))
            .collect(),
        Vector2::new(target[0], target[1]),
    )
}

impl ObstacleAvoidance {
    pub fn new(obstacles: usize) -> Result<Self, EnvError> {
        if !(1..=MAX_OBSTACLES).contains(&obstacles) {
            return Err(EnvError::InvalidOption {
                name: OBSTACLES_OPTION.into(),
                detail: format!("{obstacles} obstacles; 1 to {MAX_OBSTACLES} are supported"),
            });
        }
        let (o, t) = (OBSTACLE_REGION, TARGET_REGION);
        let mut low = vec![];
        let mut high = vec![];
        for _ in 0..obstacles {
            low.extend([o.0.x, o.0.y]);
            high.extend([o.1.x, o.1.y]);
        }
        low.extend([t.0.x, t.0.y]);
        high.extend([t.1.x, t.1.y]);
        Ok(Self {
            setup: PlanarSetup {
                id: ID,
                workspace: View {
                    min: Vector2::new(-1.05, -0.8),
                    max: Vector2::new(1.05, 0.8),
                },
                max_acceleration: 20.0,
                control_dt: 0.01,
                physics_dt: 0.001,
                max_episode_steps: 800,
            },
            obstacles,
            context_space: BoxSpace::new(low, high, Dtype::Float64),
            field: ModulatedField {
                target: Vector2::zeros(),
                obstacles: vec![],
                reactivity: EXPERT_REACTIVITY,
            },
        })
    }

    pub fn obstacle_count(&self) -> usize {
        self.obstacles
    }

    /// The expert's field for the current context.
    pub fn modulated_field(&self) -> &ModulatedField {
        &self.field
    }

    /// Whether `x` lies inside an obstacle's body.
    pub fn collides(&self, x: &Vector2<f64>) -> bool {
        self.field
            .obstacles
            .iter()
            .any(|d| (x - d.center).norm() < OBSTACLE_RADIUS)
    }

    fn clear_of_obstacles(centres: &[Vector2<f64>], x: &Vector2<f64>, gap: f64) -> bool {
        centres
            .iter()
            .all(|o| (x - o).norm() >= SAFETY_RADIUS + gap)
    }
}

impl PlanarTask for ObstacleAvoidance {
    fn setup(&self) -> &PlanarSetup {
        &self.setup
    }

    fn context_space(&self) -> &BoxSpace {
        &self.context_space
    }

    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError> {
        reject_unknown_options(extra, &[OBSTACLES_OPTION])?;
        match extra.get(OBSTACLES_OPTION) {
            Some(&n) if n != self.obstacles as f64 => Err(EnvError::InvalidOption {
                name: OBSTACLES_OPTION.into(),
                detail: format!(
                    "this environment was made with {} obstacles (the observation space \
                     depends on it); make another one for {n}",
                    self.obstacles
                ),
            }),
            _ => Ok(()),
        }
    }

    fn sample_context(&mut self, _seed: Option<u64>, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let target = uniform(rng, TARGET_REGION);
        let mut centres: Vec<Vector2<f64>> = Vec::with_capacity(self.obstacles);
        while centres.len() < self.obstacles {
            let o = uniform(rng, OBSTACLE_REGION);
            let apart = centres
                .iter()
                .all(|c| (o - c).norm() >= 2.0 * SAFETY_RADIUS + CLEARANCE);
            if apart && (o - target).norm() >= SAFETY_RADIUS + CLEARANCE {
                centres.push(o);
            }
        }
        centres
            .iter()
            .chain(std::iter::once(&target))
            .flat_map(|p| [p.x, p.y])
            .collect()
    }

    fn check_context(&self, context: &[f64]) -> Result<(), EnvError> {
        let (centres, target) = parse_context(context);
        let invalid = |detail: String| EnvError::OutOfBounds {
            what: "context",
            detail,
        };
        for (i, a) in centres.iter().enumerate() {
            if let Some(j) =
                (i + 1..centres.len()).find(|&j| (a - centres[j]).norm() < 2.0 * SAFETY_RADIUS)
            {
                return Err(invalid(format!("obstacles {i} and {j} overlap")));
            }
        }
        if !Self::clear_of_obstacles(&centres, &target, 0.0) {
            return Err(invalid(
                "the target lies within an obstacle's safety disc".into(),
            ));
        }
        Ok(())
    }

    fn set_context(&mut self, context: &[f64]) {
        let (centres, target) = parse_context(context);
        self.field = ModulatedField {
            target,
            obstacles: centres
                .into_iter()
                .map(|center| Disc {
                    center,
                    radius: SAFETY_RADIUS,
                })
                .collect(),
            reactivity: EXPERT_REACTIVITY,
        };
    }

    fn sample_start(&self, rng: &mut ChaCha8Rng) -> Vector2<f64> {
        let centres: Vec<_> = self.field.obstacles.iter().map(|d| d.center).collect();
        loop {
            let x = uniform(rng, START_REGION);
            if Self::clear_of_obstacles(&centres, &x, CLEARANCE) {
                return x;
            }
        }
    }

    fn check_start(&self, x: &Vector2<f64>) -> Result<(), EnvError> {
        if self.collides(x) {
            return Err(EnvError::OutOfBounds {
                what: "initial_position",
                detail: "the start lies inside an obstacle".into(),
            });
        }
        Ok(())
    }

    fn field(&self) -> &dyn VelocityField {
        &self.field
    }

    fn velocity_gain(&self) -> f64 {
        20.0
    }

    fn evaluate(&self, x: &Vector2<f64>, xd: &Vector2<f64>, info: &mut Info) -> Outcome {
        let distance = (x - self.field.target).norm();
        let collision = self.collides(x);
        let success = !collision && distance < SUCCESS_DISTANCE && xd.norm() < SUCCESS_SPEED;
        let flag = |b: bool| f64::from(u8::from(b));
        info.extend([
            ("distance_to_target".into(), distance),
            ("collision".into(), flag(collision)),
            (SUCCESS_INFO.into(), flag(success)),
        ]);
        Outcome {
            reward: if collision {
                COLLISION_REWARD
            } else {
                -distance
            },
            terminated: collision || success,
        }
    }

    fn draw(&self, canvas: &mut Canvas) {
        for disc in &self.field.obstacles {
            canvas.disc(&disc.center, SAFETY_RADIUS, LIGHT_GREY);
            canvas.disc(&disc.center, OBSTACLE_RADIUS, GREY);
        }
        canvas.circle(&self.field.target, 0.03, GREEN, 3.0);
    }

    /// Each obstacle as a squat cylinder of its radius, the target as a ball.
    fn context_bodies(&self, context: &[f64]) -> Vec<Body> {
        let (centres, target) = parse_context(context);
        let mut bodies: Vec<_> = centres
            .iter()
            .enumerate()
            .map(|(i, centre)| {
                let base = planar(centre);
                let top = base + OBSTACLE_RADIUS * Vector3::z();
                Body::new(
                    format!("obstacles/{i}"),
                    cylinder_between(&base, &top, OBSTACLE_RADIUS),
                    GREY,
                )
            })
            .collect();
        bodies.push(Body::new(
            "target",
            Shape::sphere(planar(&target), 0.03),
            GREEN,
        ));
        bodies
    }
}
