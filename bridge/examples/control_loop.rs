//! A stable policy beside an external controller: a 1 kHz loop, not Gymnasium, asks a
//! policy served by `ciflow serve --policy NAME=DIR` for `q̈_des` over Zenoh every
//! millisecond, and prints the latency distribution and the missed 1 ms deadlines —
//! beside the same loop's raw Zenoh query round trip (the engine's `…/ping`, echoing a
//! payload of the request's size), the floor any request over the network pays.
//!
//! ```text
//! ciflow serve --listen tcp/127.0.0.1:7447 --name lab --policy pour=out/pouring/policy
//! cargo run --release -p ciflow-bridge --example control_loop -- \
//!     tcp/127.0.0.1:7447 lab pour [--seconds 60]
//! ```
//! The loop's plant is a stand-in double integrator (see `support/control_loop.rs`);
//! on a robot, `q`, `q̇` come from the joint encoders and `q̈_des` goes to the
//! computed-torque law. `bench/control_loop.sh` runs this beside the Python loop and the
//! in-process one.

use ciflow_bridge::protocol::keys;
use ciflow_bridge::zenoh::Wait;
use ciflow_bridge::zenoh::query::ConsolidationMode;
use ciflow_bridge::{BridgeError, Client, NetworkOptions, Role};

#[path = "support/control_loop.rs"]
mod control_loop;
use control_loop::{PERIOD, Plant, run_at_1khz, seconds};

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (endpoint, engine, policy, rest) = match args.as_slice() {
        [endpoint, engine, policy, rest @ ..] => (endpoint, engine, policy, rest),
        _ => return Err("usage: control_loop ENDPOINT ENGINE POLICY [--seconds S]".into()),
    };
    let duration = seconds(rest)?;

    let client = Client::open(&NetworkOptions::endpoint(Role::Client, endpoint))?;
    let info = client.engine_info(engine)?;
    let served = info
        .policies
        .iter()
        .find(|p| &p.name == policy)
        .ok_or_else(|| format!("engine `{engine}` serves no policy `{policy}`"))?;
    let task = info
        .tasks
        .iter()
        .find(|t| t.spec.id == served.task)
        .ok_or_else(|| format!("engine `{engine}` does not serve the task {}", served.task))?;
    let mut plant = Plant::at_rest(&task.spec, served.observation_dim as usize);

    // The floor: a raw query of the same size through the same loop.
    let ping = client
        .zenoh_session()
        .declare_querier(keys::ping(engine))
        .consolidation(ConsolidationMode::None)
        .wait()?;
    let payload = vec![0_u8; 8 * plant.observation().len() + 32];
    let raw = run_at_1khz(duration, || {
        let replies = ping.get().payload(payload.clone()).wait()?;
        replies
            .recv()
            .map_err(|_| format!("engine `{engine}` did not answer the ping"))?;
        Ok::<_, Box<dyn std::error::Error + Send + Sync>>(())
    })?;
    let act = run_at_1khz(duration, || {
        let action = client.act(engine, policy, plant.observation())?;
        plant.advance(&action, PERIOD.as_secs_f64());
        Ok::<_, BridgeError>(())
    })?;
    println!(
        "{} at 1 kHz, {:.1} s each",
        served.task,
        duration.as_secs_f64()
    );
    println!("{}", raw.summary("raw Zenoh query"));
    println!("{}", act.summary("act over Zenoh "));
    println!(
        "act / raw: median {:.2}x, p99 {:.2}x",
        act.median().as_secs_f64() / raw.median().as_secs_f64(),
        act.p99().as_secs_f64() / raw.p99().as_secs_f64()
    );
    println!("final joint speed {:.4} rad/s", plant.velocity_norm());
    Ok(())
}
