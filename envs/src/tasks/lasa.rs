//! `ciflow/Lasa-v0` — the LASA handwriting shapes as planar go-to motions.
//!
//! ## Description
//! A 1 kg point mass in the plane must draw one of the 30 LASA handwriting shapes
//! ([`SHAPES`], loaded with [`crate::lasa`]) and come to rest at its end, the goal. The
//! environment replays and evaluates LASA motions through the same interface as the
//! other planar tasks: observations are in the dataset's units, so a demonstration's
//! positions and velocities are observations as they are.
//!
//! Lengths are in **millimetres** throughout, as in the dataset: positions mm, velocities
//! mm/s, actions mm/s², rewards mm. A perturbation force of 1 N therefore accelerates the
//! mass by 1 mm/s² (forces are in kg·mm/s², i.e. mN).
//!
//! ## Action space
//! `Box(-3000, 3000, (2,), float64)`: desired acceleration `ẍ_des` (mm/s²) through the
//! computed-torque layer (the demonstrations peak at about 2400 mm/s² in sharp corners);
//! out-of-range actions are refused with `OutOfBounds`.
//!
//! ## Observation space
//! `[x, y, ẋ, ẏ, g_x, g_y]`: position (mm), velocity (mm/s) and the goal `g` (mm).
//!
//! ## Context distribution
//! The context is the goal `g ∈ [−10, 10]²` mm; the whole shape moves with it (the expert
//! and the starts are translated by `g`). `reset` uses the dataset's goal, the origin,
//! unless `options.context` sets it; `set_context` moves it mid-episode.
//!
//! ## Expert
//! [`DemoField`]: kernel regression (σ = 3 mm) of the seven demonstrations' velocities
//! with a pull onto the demonstrated paths, blended into a linear attractor to the goal
//! away from the demonstrations and near the goal; tracked with `k_v = 20 /s`, clipped to
//! the action space.
//!
//! ## Rewards
//! `−‖x − g‖` (mm) per step. `info`: `distance_to_goal` (mm), `is_success` (1 within
//! [`GOAL_TOLERANCE`] of the goal), `shape` (the shape's index in [`SHAPES`]), `time` (s).
//!
//! ## Starting state
//! The start of one of the shape's seven demonstrations (option `demo`, `0..7`; drawn
//! uniformly when unset), plus a uniform draw in the disc of radius `start_noise` mm
//! (option, default 0), translated by the goal; zero velocity (the demonstrations start
//! nearly at rest; pass the demonstration's first velocity as `initial_velocity` to replay
//! it exactly). `options.initial_position` / `initial_velocity` override them.
//!
//! ## Episode end
//! Terminated on success, whatever the speed: the demonstrations themselves reach the
//! goal at up to 20 mm/s and stop there abruptly. Truncated after 1500 steps (15 s; the
//! longest demonstration lasts 8.7 s).
//!
//! ## Rendering
//! The shape's seven demonstrations (grey), the path so far (blue), the mass (black) and
//! the goal (green), framed on the demonstrations.
//!
//! ## Arguments
//! `shape` (index into [`SHAPES`], `0..30`; default 0, `Angle`): the shape drawn unless a
//! reset's `shape` option picks another. Numbers only cross the registry and the bridge;
//! names are resolved with [`shape_index`] (the registry lists [`SHAPES`] as the names of
//! `shape`, so `ciflow demos --kwarg shape=Sshape` works), or in Rust with
//! [`make_named`]. The dataset is converted on the first reset that needs a shape, so a
//! missing dataset is an error of `reset` (`EnvError::Lasa`), never of construction.
//!
//! ## Version history
//! v0: initial version.

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;
use std::sync::{Arc, LazyLock, Mutex};

use nalgebra::Vector2;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::env::{EnvError, Info, Outcome, SUCCESS_INFO};
use crate::expert::demo_field::{DemoField, Sample};
use crate::expert::tracking::VelocityField;
use crate::planar::{PlanarEnv, PlanarSetup, PlanarTask, index_option, reject_unknown_options};
use crate::raster::{Canvas, GREEN, GREY, View};
use crate::scene::{Body, Shape, planar};
use crate::space::{BoxSpace, Dtype};

pub const ID: &str = "ciflow/Lasa-v0";
/// The 30 shapes, in the order of [`crate::lasa::shape_names`]; a shape's index is its
/// number in options and `info`.
pub const SHAPES: [&str; 30] = [
    "Angle",
    "BendedLine",
    "CShape",
    "DoubleBendedLine",
    "GShape",
    "JShape",
    "JShape_2",
    "Khamesh",
    "LShape",
    "Leaf_1",
    "Leaf_2",
    "Line",
    "Multi_Models_1",
    "Multi_Models_2",
    "Multi_Models_3",
    "Multi_Models_4",
    "NShape",
    "PShape",
    "RShape",
    "Saeghe",
    "Sharpc",
    "Sine",
    "Snake",
    "Spoon",
    "Sshape",
    "Trapezoid",
    "WShape",
    "Worm",
    "Zshape",
    "heee",
];
/// Distance to the goal within which the shape is done, mm.
pub const GOAL_TOLERANCE: f64 = 1.0;
/// Bound of each goal coordinate, mm.
pub const MAX_GOAL_OFFSET: f64 = 10.0;
pub const SHAPE_OPTION: &str = "shape";
pub const DEMO_OPTION: &str = "demo";
pub const START_NOISE_OPTION: &str = "start_noise";
/// Space around the shape in `render`, mm.
const VIEW_MARGIN: f64 = 5.0;
/// Every fifth sample of a demonstration is enough to draw it.
const DRAWN_POINT_STRIDE: usize = 5;

/// The index of the shape called `name` in [`SHAPES`].
pub fn shape_index(name: &str) -> Result<usize, EnvError> {
    SHAPES
        .iter()
        .position(|s| *s == name)
        .ok_or_else(|| EnvError::InvalidOption {
            name: SHAPE_OPTION.into(),
            detail: format!("unknown LASA shape `{name}`; known: {}", SHAPES.join(", ")),
        })
}

/// One shape's demonstrations, relative to the goal, and its expert.
#[derive(Clone, Debug)]
struct ShapeModel {
    field: DemoField,
    starts: Vec<Vector2<f64>>,
    /// Demonstrated paths, for `render` (shared by every environment of the shape).
    paths: Arc<[Vec<Vector2<f64>>]>,
    /// What `render` shows: the paths wherever the goal may move them.
    view: View,
}

/// The shapes loaded in this process: every environment of a shape shares its
/// demonstrations and kernel centres (tens of kB per shape), cloning only the goal.
static LOADED: LazyLock<Mutex<BTreeMap<usize, ShapeModel>>> = LazyLock::new(Default::default);

impl ShapeModel {
    /// Shape `shape`'s model, loaded once per process.
    fn shared(shape: usize) -> Result<Self, EnvError> {
        let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
        if let Entry::Vacant(slot) = loaded.entry(shape) {
            slot.insert(Self::load(shape)?);
        }
        Ok(loaded[&shape].clone())
    }

    fn load(shape: usize) -> Result<Self, EnvError> {
        let failed = |detail: String| EnvError::InvalidOption {
            name: SHAPE_OPTION.into(),
            detail,
        };
        let data = crate::lasa::load(SHAPES[shape]).map_err(|source| EnvError::Lasa {
            option: SHAPE_OPTION,
            shape: SHAPES[shape],
            source,
        })?;
        let vector = |[x, y]: [f64; 2]| Vector2::new(x, y);
        let demos: Vec<Vec<Sample>> = data
            .demos
            .iter()
            .map(|demo| {
                demo.positions
                    .iter()
                    .zip(&demo.velocities)
                    .map(|(p, v)| Sample {
                        position: vector(*p),
                        velocity: vector(*v),
                    })
                    .collect()
            })
            .collect();
        let field = DemoField::new(&demos)
            .ok_or_else(|| failed(format!("shape `{}` has no samples", SHAPES[shape])))?;
        let margin = Vector2::repeat(MAX_GOAL_OFFSET + VIEW_MARGIN);
        let positions = || demos.iter().flatten().map(|s| s.position);
        let view = View {
            min: positions().fold(Vector2::zeros(), |a, p| a.inf(&p)) - margin,
            max: positions().fold(Vector2::zeros(), |a, p| a.sup(&p)) + margin,
        };
        Ok(Self {
            view,
            field,
            starts: demos.iter().map(|d| d[0].position).collect(),
            paths: demos
                .iter()
                .map(|d| {
                    d.iter()
                        .step_by(DRAWN_POINT_STRIDE)
                        .map(|s| s.position)
                        .collect()
                })
                .collect(),
        })
    }
}

/// The LASA task (see the module docs).
pub struct Lasa {
    setup: PlanarSetup,
    context_space: BoxSpace,
    /// The `shape` argument: the shape of resets that do not choose one.
    default_shape: usize,
    shape: usize,
    /// The `demo` option of the current reset.
    demo: Option<usize>,
    start_noise: f64,
    /// Shapes loaded so far; `shape` is among them after a successful reset.
    models: BTreeMap<usize, ShapeModel>,
}

/// The environment drawing shape `shape` (an index into [`SHAPES`]) by default.
pub fn make(shape: usize) -> Result<PlanarEnv<Lasa>, EnvError> {
    PlanarEnv::new(Lasa::new(shape)?)
}

/// The environment drawing the shape called `name` by default.
pub fn make_named(name: &str) -> Result<PlanarEnv<Lasa>, EnvError> {
    make(shape_index(name)?)
}

impl Lasa {
    pub fn new(shape: usize) -> Result<Self, EnvError> {
        if shape >= SHAPES.len() {
            return Err(EnvError::InvalidOption {
                name: SHAPE_OPTION.into(),
                detail: format!("{shape} is not a shape index in [0, {})", SHAPES.len()),
            });
        }
        let g = MAX_GOAL_OFFSET;
        Ok(Self {
            setup: PlanarSetup {
                id: ID,
                // Every shape fits; `reset` narrows it to the shape's demonstrations.
                workspace: View {
                    min: Vector2::new(-60.0, -60.0),
                    max: Vector2::new(60.0, 60.0),
                },
                max_acceleration: 3000.0,
                control_dt: 0.01,
                physics_dt: 0.001,
                max_episode_steps: 1500,
            },
            context_space: BoxSpace::new(vec![-g; 2], vec![g; 2], Dtype::Float64),
            default_shape: shape,
            shape,
            demo: None,
            start_noise: 0.0,
            models: BTreeMap::new(),
        })
    }

    /// The index in [`SHAPES`] of the shape of the current episode.
    pub fn shape(&self) -> usize {
        self.shape
    }

    fn model(&self) -> &ShapeModel {
        &self.models[&self.shape]
    }

    /// The expert's field of the current episode (`None` before the first reset).
    pub fn demo_field(&self) -> Option<&DemoField> {
        self.models.get(&self.shape).map(|m| &m.field)
    }

    fn goal(&self) -> Vector2<f64> {
        self.model().field.goal
    }
}

impl PlanarTask for Lasa {
    fn setup(&self) -> &PlanarSetup {
        &self.setup
    }

    fn context_space(&self) -> &BoxSpace {
        &self.context_space
    }

    fn configure(&mut self, extra: &BTreeMap<String, f64>) -> Result<(), EnvError> {
        reject_unknown_options(extra, &[SHAPE_OPTION, DEMO_OPTION, START_NOISE_OPTION])?;
        let shape = index_option(extra, SHAPE_OPTION, SHAPES.len())?.unwrap_or(self.default_shape);
        let start_noise = extra.get(START_NOISE_OPTION).copied().unwrap_or(0.0);
        if !(start_noise.is_finite() && start_noise >= 0.0) {
            return Err(EnvError::InvalidOption {
                name: START_NOISE_OPTION.into(),
                detail: format!("{start_noise} is not a radius in mm"),
            });
        }
        if let Entry::Vacant(slot) = self.models.entry(shape) {
            slot.insert(ShapeModel::shared(shape)?);
        }
        let demos = self.models[&shape].starts.len();
        self.demo = index_option(extra, DEMO_OPTION, demos)?;
        self.setup.workspace = self.models[&shape].view;
        self.shape = shape;
        self.start_noise = start_noise;
        Ok(())
    }

    fn sample_context(&mut self, _seed: Option<u64>, _rng: &mut ChaCha8Rng) -> Vec<f64> {
        vec![0.0, 0.0]
    }

    fn set_context(&mut self, context: &[f64]) {
        let shape = self.shape;
        if let Some(model) = self.models.get_mut(&shape) {
            model.field.goal = Vector2::new(context[0], context[1]);
        }
    }

    fn sample_start(&self, rng: &mut ChaCha8Rng) -> Vector2<f64> {
        let starts = &self.model().starts;
        let demo = self
            .demo
            .unwrap_or_else(|| rng.random_range(0..starts.len()));
        let radius = self.start_noise * rng.random::<f64>().sqrt();
        let angle = rng.random_range(0.0..std::f64::consts::TAU);
        self.goal() + starts[demo] + radius * Vector2::new(angle.cos(), angle.sin())
    }

    fn field(&self) -> &dyn VelocityField {
        &self.model().field
    }

    fn velocity_gain(&self) -> f64 {
        20.0
    }

    fn evaluate(&self, x: &Vector2<f64>, _xd: &Vector2<f64>, info: &mut Info) -> Outcome {
        let distance = (x - self.goal()).norm();
        let success = distance < GOAL_TOLERANCE;
        info.extend([
            ("distance_to_goal".into(), distance),
            (SUCCESS_INFO.into(), f64::from(u8::from(success))),
            ("shape".into(), self.shape as f64),
        ]);
        Outcome {
            reward: -distance,
            terminated: success,
        }
    }

    fn draw(&self, canvas: &mut Canvas) {
        let goal = self.goal();
        for path in self.model().paths.iter() {
            let shifted: Vec<_> = path.iter().map(|p| p + goal).collect();
            canvas.polyline(&shifted, false, GREY, 1.0);
        }
        canvas.circle(&goal, 2.0, GREEN, 3.0);
    }

    /// The goal `context` as a ball and, once a shape is loaded, its demonstrated paths
    /// moved with the goal.
    fn context_bodies(&self, context: &[f64]) -> Vec<Body> {
        let goal = Vector2::new(context[0], context[1]);
        let paths = self.models.get(&self.shape).map_or(&[][..], |m| &m.paths);
        let mut bodies: Vec<_> = paths
            .iter()
            .enumerate()
            .map(|(i, path)| {
                let points = path.iter().map(|p| planar(&(p + goal))).collect();
                let curve = Shape::Curve {
                    points,
                    closed: false,
                    radius: 0.3,
                };
                Body::new(format!("demonstrations/{i}"), curve, GREY)
            })
            .collect();
        bodies.push(Body::new("goal", Shape::sphere(planar(&goal), 2.0), GREEN));
        bodies
    }
}
