//! The Rust half of `bench/dynamics_vs_pinocchio.sh`: ciflow's dynamics on a URDF robot,
//! over states read from a file that the C++ half (`bench/pinocchio/timing.cpp`) reads too.
//!
//! ```text
//! dynamics_timing ROBOT.urdf STATES.txt values   # JSON: every algorithm's output per state
//! dynamics_timing ROBOT.urdf STATES.txt time MS  # JSON: ns per call, best of batches of ~MS ms
//! ```
//!
//! `STATES.txt`: a line `nv count`, then one line per state holding `q`, `q̇`, `q̈`, `τ`
//! (4 nv numbers).

use std::hint::black_box;
use std::time::Instant;

use anyhow::{Context, Result, bail, ensure};
use ciflow_engine::algorithm::{
    DynamicsError, coriolis_matrix, crba, forward_dynamics, generalized_gravity, nonlinear_effects,
    rnea,
};
use ciflow_engine::math::{DMatrix, DVector, Real};
use ciflow_engine::model::{Data, Model};
use serde_json::{Map, Value, json};

/// Timed batches per algorithm; the fastest batch counts (load on a shared machine only
/// ever adds time).
const BATCHES: usize = 25;

/// One state of the robot: `q`, `q̇`, `q̈` and `τ`.
struct State {
    q: Vec<Real>,
    qd: Vec<Real>,
    qdd: Vec<Real>,
    tau: Vec<Real>,
}

/// One algorithm under test, by the name both halves of the benchmark print: `run` leaves
/// its result in the workspace, where `output` reads it (outside the timed loop).
struct Algorithm {
    name: &'static str,
    run: fn(&Model, &mut Data, &State) -> Result<(), DynamicsError>,
    output: fn(&Data) -> Vec<Real>,
}

fn vector(v: &DVector) -> Vec<Real> {
    v.as_slice().to_vec()
}

/// Row-major entries of a matrix.
fn matrix(m: &DMatrix) -> Vec<Real> {
    m.transpose().as_slice().to_vec()
}

const ALGORITHMS: [Algorithm; 6] = [
    Algorithm {
        name: "rnea",
        run: |model, data, s| rnea(model, data, &s.q, &s.qd, &s.qdd).map(|_| ()),
        output: |data| vector(&data.tau),
    },
    Algorithm {
        name: "crba",
        run: |model, data, s| crba(model, data, &s.q).map(|_| ()),
        output: |data| matrix(&data.m),
    },
    Algorithm {
        name: "gravity",
        run: |model, data, s| generalized_gravity(model, data, &s.q).map(|_| ()),
        output: |data| vector(&data.g),
    },
    Algorithm {
        name: "nonlinear_effects",
        run: |model, data, s| nonlinear_effects(model, data, &s.q, &s.qd).map(|_| ()),
        output: |data| vector(&data.nle),
    },
    Algorithm {
        name: "coriolis",
        run: |model, data, s| coriolis_matrix(model, data, &s.q, &s.qd).map(|_| ()),
        output: |data| matrix(&data.c),
    },
    Algorithm {
        name: "forward_dynamics",
        run: |model, data, s| forward_dynamics(model, data, &s.q, &s.qd, &s.tau).map(|_| ()),
        output: |data| vector(&data.ddq),
    },
];

fn read_states(path: &str) -> Result<Vec<State>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {path}"))?;
    let mut lines = text.lines();
    let header: Vec<usize> = lines
        .next()
        .context("empty states file")?
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .context("header `nv count`")?;
    let [nv, count] = header[..] else {
        bail!("header must be `nv count`, got {header:?}");
    };
    let states = lines
        .map(|line| {
            let numbers: Vec<Real> = line
                .split_whitespace()
                .map(str::parse)
                .collect::<Result<_, _>>()
                .with_context(|| format!("state line `{line}`"))?;
            ensure!(numbers.len() == 4 * nv, "a state needs {} numbers", 4 * nv);
            let mut parts = numbers.chunks(nv).map(<[Real]>::to_vec);
            let mut next = || parts.next().expect("four chunks of nv");
            Ok(State {
                q: next(),
                qd: next(),
                qdd: next(),
                tau: next(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    ensure!(
        states.len() == count,
        "expected {count} states, found {}",
        states.len()
    );
    Ok(states)
}

/// Every algorithm's output for every state.
fn values(model: &Model, data: &mut Data, states: &[State]) -> Result<Value> {
    let mut out = Map::new();
    for algorithm in &ALGORITHMS {
        let results = states
            .iter()
            .map(|s| {
                (algorithm.run)(model, data, s)?;
                Ok((algorithm.output)(data))
            })
            .collect::<Result<Vec<_>, DynamicsError>>()
            .with_context(|| algorithm.name)?;
        out.insert(algorithm.name.into(), json!(results));
    }
    Ok(Value::Object(out))
}

/// Nanoseconds per call of each algorithm: passes over all states in batches of about
/// `batch_ms`, the fastest batch's mean.
fn time(model: &Model, data: &mut Data, states: &[State], batch_ms: f64) -> Result<Value> {
    let mut out = Map::new();
    for algorithm in &ALGORITHMS {
        let mut pass = || -> Result<(), DynamicsError> {
            for s in states {
                (algorithm.run)(model, black_box(&mut *data), black_box(s))?;
            }
            Ok(())
        };
        let start = Instant::now();
        pass()?;
        let passes = (batch_ms * 1e6 / start.elapsed().as_nanos().max(1) as f64).ceil() as usize;
        let mut best = f64::INFINITY;
        for _ in 0..BATCHES {
            let start = Instant::now();
            for _ in 0..passes {
                pass()?;
            }
            let ns = start.elapsed().as_nanos() as f64 / (passes * states.len()) as f64;
            best = best.min(ns);
        }
        out.insert(algorithm.name.into(), json!(best));
    }
    Ok(Value::Object(out))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let usage = "usage: dynamics_timing ROBOT.urdf STATES.txt (values | time BATCH_MS)";
    ensure!(args.len() >= 4, "{usage}");
    let urdf = std::fs::read_to_string(&args[1]).with_context(|| format!("reading {}", args[1]))?;
    let model = Model::from_urdf_str(&urdf).context("parsing the URDF")?;
    let mut data = Data::new(&model);
    let states = read_states(&args[2])?;
    ensure!(
        states.iter().all(|s| s.q.len() == model.nv()),
        "states are for another robot (nv = {})",
        model.nv()
    );
    let report = match (args[3].as_str(), args.get(4)) {
        ("values", None) => values(&model, &mut data, &states)?,
        ("time", Some(batch_ms)) => {
            let batch_ms = batch_ms.parse().context("BATCH_MS")?;
            time(&model, &mut data, &states, batch_ms)?
        }
        _ => bail!("{usage}"),
    };
    println!("{report}");
    Ok(())
}
