//! Serve every task and step one over Zenoh: an engine and a client in one process, each
//! on its own Zenoh session, meeting on a loopback TCP endpoint as two processes would.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example serve_and_step -- [ENDPOINT]
//! ```
//! (default `tcp/127.0.0.1:7447`). The client opens a limit-cycle session, resets it
//! with a seed and lets the task's expert act for 200 steps.

use std::collections::BTreeMap;

use ciflow_bridge::{Client, EngineServer, NetworkOptions, Role, ServerOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let endpoint = std::env::args().nth(1);
    let endpoint = endpoint
        .as_deref()
        .unwrap_or(ciflow_bridge::DEFAULT_ENDPOINT);

    // The engine listens; `ciflow serve` does the same from the command line.
    let engine = EngineServer::open(
        &NetworkOptions::endpoint(Role::Engine, endpoint),
        ServerOptions::default(),
    )?;
    // The client connects and opens a session of one environment.
    let client = Client::open(&NetworkOptions::endpoint(Role::Client, endpoint))?;
    let env = client.make(engine.name(), "ciflow/LimitCycle-v0", 1, &BTreeMap::new())?;
    println!("session {} on engine {}", env.session_id(), env.engine());

    let (mut observation, _info) = env.reset(Some(0), None)?;
    let mut total_reward = 0.0;
    for _ in 0..200 {
        let action = env.expert(0)?;
        let step = env.step(&action)?;
        total_reward += step.reward;
        observation = step.observation;
    }
    println!("after 200 expert steps: observation {observation:.3?}, return {total_reward:.3}");
    env.close()?;
    Ok(())
}
