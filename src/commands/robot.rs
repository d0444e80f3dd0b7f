//! `ciflow robot`: kinematics and dynamics of a robot model at a given state, as JSON.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use ciflow_engine::math::{DMatrix, DVector, Real, Vector3};
use ciflow_engine::robot::{LockedJoint, PointMass2d, Robot, SerialChain, UrdfOptions, panda};
use clap::{Args, Subcommand};
use serde_json::{Value, json};

#[derive(Args, Debug)]
pub struct RobotArgs {
    #[command(flatten)]
    urdf: UrdfArgs,
    #[command(subcommand)]
    robot: RobotChoice,
}

/// A serial arm from a URDF file: `ciflow robot --urdf FILE <query>`.
#[derive(Args, Debug)]
struct UrdfArgs {
    /// The robot's URDF (a fixed-base chain of revolute, continuous, prismatic and fixed
    /// joints).
    #[arg(long, value_name = "FILE")]
    urdf: Option<PathBuf>,
    /// The tool frame, a link name (default: the last link).
    #[arg(long, value_name = "LINK", requires = "urdf")]
    tool: Option<String>,
    /// Joints held fixed, as NAME (at 0) or NAME=POSITION, comma-separated; e.g. one
    /// finger of a gripper.
    #[arg(long, value_name = "NAMES", value_delimiter = ',', requires = "urdf")]
    lock_joints: Vec<LockedJoint>,
    /// Reflected rotor inertias of the moving joints in chain order, comma-separated
    /// (kg·m², kg for a prismatic joint); URDF cannot carry them (default: zero).
    #[arg(long, value_name = "VALUES", value_delimiter = ',', requires = "urdf")]
    armature: Option<Vec<Real>>,
}

#[derive(Subcommand, Debug)]
enum RobotChoice {
    /// The Franka Emika Panda (7 joints, shipped URDF, hand as tool frame).
    Panda {
        #[command(subcommand)]
        query: Query,
    },
    /// A point mass in a horizontal plane (2 coordinates x, y).
    PointMass {
        /// Mass in kg.
        #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
        mass: Real,
        #[command(subcommand)]
        query: Query,
    },
    /// A query on the robot given by --urdf.
    #[command(flatten)]
    Urdf(Query),
}

/// Joint values as a comma-separated list, e.g. `0,-0.78,0,-2.35,0,1.57,0.78`.
#[derive(Args, Debug)]
struct Position {
    /// Joint positions q (rad or m), comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true
    )]
    q: Vec<Real>,
}

#[derive(Args, Debug)]
struct Velocity {
    /// Joint velocities q̇, comma-separated (default: zero).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    qd: Option<Vec<Real>>,
}

#[derive(Subcommand, Debug)]
enum Query {
    /// τ = M(q) q̈ + C(q, q̇) q̇ + g(q) (RNEA).
    InverseDynamics {
        #[command(flatten)]
        position: Position,
        #[command(flatten)]
        velocity: Velocity,
        /// Joint accelerations q̈, comma-separated (default: zero).
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
        qdd: Option<Vec<Real>>,
    },
    /// q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q)).
    ForwardDynamics {
        #[command(flatten)]
        position: Position,
        #[command(flatten)]
        velocity: Velocity,
        /// Joint torques τ, comma-separated (default: zero).
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
        tau: Option<Vec<Real>>,
    },
    /// The joint-space inertia matrix M(q) (CRBA).
    MassMatrix {
        #[command(flatten)]
        position: Position,
    },
    /// The generalized gravity g(q).
    Gravity {
        #[command(flatten)]
        position: Position,
    },
    /// The Coriolis matrix C(q, q̇) (Ṁ = C + Cᵀ).
    Coriolis {
        #[command(flatten)]
        position: Position,
        #[command(flatten)]
        velocity: Velocity,
    },
    /// Placements of the frames in the base frame (one frame with --link).
    ForwardKinematics {
        #[command(flatten)]
        position: Position,
        /// A frame, by index or name (default: all frames).
        #[arg(long)]
        link: Option<String>,
    },
    /// The world-aligned geometric Jacobian [linear; angular] of a frame's origin.
    Jacobian {
        #[command(flatten)]
        position: Position,
        /// A frame, by index or name (default: the tool frame).
        #[arg(long)]
        link: Option<String>,
    },
}

pub fn run(args: RobotArgs) -> Result<()> {
    let (mut robot, query): (Box<dyn Robot>, Query) = match (args.urdf.urdf, args.robot) {
        (None, RobotChoice::Panda { query }) => (Box::new(panda()), query),
        (None, RobotChoice::PointMass { mass, query }) => (
            Box::new(PointMass2d::new(mass).context("invalid point mass")?),
            query,
        ),
        (Some(path), RobotChoice::Urdf(query)) => {
            let options = UrdfOptions {
                locked: args.urdf.lock_joints,
                tool: args.urdf.tool,
                armature: args.urdf.armature,
            };
            let chain = SerialChain::from_urdf_file(&path, &options)
                .with_context(|| format!("loading the robot from {}", path.display()))?;
            (Box::new(chain), query)
        }
        (Some(_), _) => bail!("--urdf gives the robot: leave out `panda` / `point-mass`"),
        (None, RobotChoice::Urdf(_)) => {
            bail!("name the robot: `panda`, `point-mass`, or --urdf FILE")
        }
    };
    let output = evaluate(robot.as_mut(), query)?;
    println!("{}", serde_json::to_string_pretty(&output)?);
    Ok(())
}

fn evaluate(robot: &mut dyn Robot, query: Query) -> Result<Value> {
    let n = robot.dof();
    let name = robot.name().to_owned();
    let or_zero = |values: Option<Vec<Real>>| values.unwrap_or_else(|| vec![0.0; n]);
    let mut vector = DVector::zeros(n);
    let mut matrix = DMatrix::zeros(n, n);
    let value = match query {
        Query::InverseDynamics {
            position,
            velocity,
            qdd,
        } => {
            let (qd, qdd) = (or_zero(velocity.qd), or_zero(qdd));
            robot
                .inverse_dynamics(&position.q, &qd, &qdd, &mut vector)
                .context("inverse dynamics")?;
            json!({ "robot": name, "tau": vector.as_slice() })
        }
        Query::ForwardDynamics {
            position,
            velocity,
            tau,
        } => {
            let (qd, tau) = (or_zero(velocity.qd), or_zero(tau));
            robot
                .forward_dynamics(&position.q, &qd, &tau, &mut vector)
                .context("forward dynamics")?;
            json!({ "robot": name, "qdd": vector.as_slice() })
        }
        Query::MassMatrix { position } => {
            robot
                .mass_matrix(&position.q, &mut matrix)
                .context("mass matrix")?;
            json!({ "robot": name, "mass_matrix": rows(&matrix) })
        }
        Query::Gravity { position } => {
            robot.gravity(&position.q, &mut vector).context("gravity")?;
            json!({ "robot": name, "gravity": vector.as_slice() })
        }
        Query::Coriolis { position, velocity } => {
            let qd = or_zero(velocity.qd);
            robot
                .coriolis_matrix(&position.q, &qd, &mut matrix)
                .context("Coriolis matrix")?;
            json!({ "robot": name, "coriolis": rows(&matrix) })
        }
        Query::ForwardKinematics { position, link } => {
            let frames = match link {
                Some(link) => vec![robot.find_frame(&link)?],
                None => (0..robot.frames().len()).collect(),
            };
            let placements = frames
                .into_iter()
                .map(|frame| placement(robot, &position.q, frame))
                .collect::<Result<Vec<_>>>()?;
            json!({ "robot": name, "frames": placements })
        }
        Query::Jacobian { position, link } => {
            let frame = match link {
                Some(link) => robot.find_frame(&link)?,
                None => robot.end_effector(),
            };
            let mut jacobian = DMatrix::zeros(6, n);
            robot
                .frame_jacobian(&position.q, frame, &Vector3::zeros(), &mut jacobian)
                .context("Jacobian")?;
            json!({
                "robot": name,
                "frame": robot.frames()[frame].name,
                "jacobian": rows(&jacobian),
            })
        }
    };
    Ok(value)
}

fn placement(robot: &dyn Robot, q: &[Real], frame: usize) -> Result<Value> {
    let isometry = robot
        .frame_placement(q, frame)
        .context("forward kinematics")?;
    let rotation = isometry.rotation.to_rotation_matrix().into_inner();
    let quaternion = isometry.rotation.coords;
    Ok(json!({
        "index": frame,
        "name": robot.frames()[frame].name,
        "translation": isometry.translation.vector.as_slice(),
        "rotation": (0..3).map(|i| (0..3).map(|j| rotation[(i, j)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
        "quaternion_xyzw": quaternion.as_slice(),
    }))
}

/// A matrix as a list of rows.
fn rows(matrix: &DMatrix) -> Vec<Vec<Real>> {
    matrix
        .row_iter()
        .map(|row| row.iter().copied().collect())
        .collect()
}
