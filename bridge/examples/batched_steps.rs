//! Batched stepping of one task on an engine, from the Rust client: `NUM_ENVS`
//! environments in one session, every `step_batch` request stepping all of them (zero
//! actions, next-step autoreset), for `SECONDS`; prints `{"task", "num_envs",
//! "env_steps_per_s"}` as one JSON line. `bench/panda_vs_mujoco.py` runs it against
//! `ciflow serve` for the Panda beside MuJoCo.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example batched_steps -- ENDPOINT TASK NUM_ENVS SECONDS
//! ```

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use ciflow_bridge::{Client, NetworkOptions, Role};

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [endpoint, task, num_envs, seconds] = &args[..] else {
        return Err("usage: batched_steps ENDPOINT TASK NUM_ENVS SECONDS".into());
    };
    let (num_envs, seconds): (u32, f64) = (num_envs.parse()?, seconds.parse()?);
    let client = Client::open(&NetworkOptions::endpoint(Role::Client, endpoint))?;
    let engine = client
        .discover()?
        .into_iter()
        .find(|e| e.tasks.iter().any(|t| t.is_named(task)))
        .ok_or_else(|| format!("no engine at {endpoint} serves {task}"))?
        .name;
    let batch = client.make(&engine, task, num_envs, &BTreeMap::new())?;
    batch.reset_batch(Some(0), None)?;
    let actions = vec![0.0; num_envs as usize * batch.spec().action_space.dim()];
    batch.step_batch(&actions)?;
    let (start, budget) = (Instant::now(), Duration::from_secs_f64(seconds));
    let mut rounds = 0u64;
    while start.elapsed() < budget {
        batch.step_batch(&actions)?;
        rounds += 1;
    }
    let rate = (rounds * u64::from(num_envs)) as f64 / start.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({"task": task, "num_envs": num_envs, "env_steps_per_s": rate})
    );
    batch.close()?;
    Ok(())
}
