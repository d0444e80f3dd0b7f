//! The Panda in ciflow's simulator driven open loop by given joint torques, for the
//! comparison with MuJoCo (`bench/panda_vs_mujoco.py`): reads a JSON request on stdin,
//! prints the trajectory as JSON.
//!
//! ```text
//! {"q0": [7], "qd0": [7], "physics_dt": 0.001, "tau": [[7], ...]}   → stdin
//! {"armature": [7], "q": [[7], ...], "qd": [[7], ...]}              ← stdout
//! ```
//!
//! One physics step per torque row (semi-implicit Euler, the shipped Panda with its
//! armature); row `k` of the output is the state after `k + 1` steps.

use anyhow::{Context, Result, ensure};
use ciflow_engine::robot::panda;
use ciflow_engine::sim::{Integrator, SimConfig, Simulator};
use serde::{Deserialize, Serialize};

#[derive(Deserialize)]
struct Request {
    q0: Vec<f64>,
    qd0: Vec<f64>,
    physics_dt: f64,
    tau: Vec<Vec<f64>>,
}

#[derive(Serialize)]
struct Trajectory {
    /// The joints' armature (reflected rotor inertia, kg·m²), which URDF cannot carry.
    armature: Vec<f64>,
    q: Vec<Vec<f64>>,
    qd: Vec<Vec<f64>>,
}

fn main() -> Result<()> {
    let request: Request =
        serde_json::from_reader(std::io::stdin().lock()).context("reading the request")?;
    ensure!(!request.tau.is_empty(), "no torques to apply");
    let config = SimConfig {
        physics_dt: request.physics_dt,
        control_dt: request.physics_dt,
        integrator: Integrator::SemiImplicitEuler,
    };
    let robot = panda();
    let armature = robot.model().armature().as_slice().to_vec();
    let mut simulator = Simulator::new(Box::new(robot), config)?;
    simulator.reset(&request.q0, &request.qd0)?;
    let mut trajectory = Trajectory {
        armature,
        q: Vec::with_capacity(request.tau.len()),
        qd: Vec::with_capacity(request.tau.len()),
    };
    for (k, tau) in request.tau.iter().enumerate() {
        let report = simulator
            .step_torque(tau)
            .with_context(|| format!("step {k}"))?;
        ensure!(
            report.end_stops.is_empty(),
            "step {k} hit an end stop: choose torques that stay inside the joint range"
        );
        trajectory.q.push(simulator.q().as_slice().to_vec());
        trajectory.qd.push(simulator.qd().as_slice().to_vec());
    }
    serde_json::to_writer(std::io::stdout().lock(), &trajectory)?;
    Ok(())
}
