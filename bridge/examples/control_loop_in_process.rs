//! The pure-Rust policy as a library inside a 1 kHz control loop, no Zenoh: load a
//! checkpoint, ask it for `q̈_des` every millisecond, print the latency distribution and
//! the missed 1 ms deadlines (the same loop as `control_loop`, which asks over Zenoh).
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example control_loop_in_process -- \
//!     CHECKPOINT_DIR [--seconds 60]
//! ```

use std::path::Path;

use ciflow_envs::actor::{Actor, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::registry;

#[path = "support/control_loop.rs"]
mod control_loop;
use control_loop::{PERIOD, Plant, run_at_1khz, seconds};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, rest @ ..] = args.as_slice() else {
        return Err("usage: control_loop_in_process CHECKPOINT_DIR [--seconds S]".into());
    };
    let duration = seconds(rest)?;
    let model = Model::load(Path::new(dir), None)?;
    let spec = registry::make(model.task())?.spec().clone();
    let mut actor = Actor::new(&model, &spec, DEFAULT_VELOCITY_GAIN)?;
    let mut plant = Plant::at_rest(&spec, spec.observation_space.dim());
    let mut action = vec![0.0; spec.action_space.dim()];

    let report = run_at_1khz(duration, || {
        actor.act(plant.observation(), &mut action)?;
        plant.advance(&action, PERIOD.as_secs_f64());
        Ok::<_, ciflow_envs::actor::ActorError>(())
    })?;
    println!("{} at 1 kHz for {:.1} s", spec.id, duration.as_secs_f64());
    println!("{}", report.summary("act in process"));
    println!("final joint speed {:.4} rad/s", plant.velocity_norm());
    Ok(())
}
