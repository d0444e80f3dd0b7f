//! Batched stepping of one task from the Rust client: `NUM_ENVS` environments, every step
//! one request per engine stepping all of that engine's environments (zero actions,
//! next-step autoreset), for `SECONDS`; prints `{"task", "num_envs", "engines",
//! "env_steps_per_s"}` as one JSON line. Without `ENGINES` the first engine at `ENDPOINT`
//! that serves the task takes them all; with a comma-separated list they are spread over
//! those engines ([`ciflow_bridge::vector`]: the requests in flight together).
//! `bench/panda_vs_mujoco.py` runs it against `ciflow serve` for the Panda beside MuJoCo.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example batched_steps -- ENDPOINT TASK NUM_ENVS SECONDS [ENGINES]
//! ```

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use ciflow_bridge::vector::{reset_batches, step_batches};
use ciflow_bridge::{Client, NetworkOptions, RemoteEnv, Role};

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (endpoint, task, num_envs, seconds, engines) = match &args[..] {
        [endpoint, task, num_envs, seconds] => (endpoint, task, num_envs, seconds, None),
        [endpoint, task, num_envs, seconds, engines] => {
            (endpoint, task, num_envs, seconds, Some(engines))
        }
        _ => return Err("usage: batched_steps ENDPOINT TASK NUM_ENVS SECONDS [ENGINES]".into()),
    };
    let (num_envs, seconds): (u32, f64) = (num_envs.parse()?, seconds.parse()?);
    let client = Client::open(&NetworkOptions::endpoint(Role::Client, endpoint))?;
    let engines: Vec<String> = match engines {
        Some(list) => list.split(',').map(str::to_owned).collect(),
        None => vec![
            client
                .first_engine_serving(Some(task))?
                .ok_or_else(|| format!("no engine at {endpoint} serves {task}"))?,
        ],
    };
    // Shares differ by at most one, in the order of the engines.
    let count = engines.len() as u32;
    if num_envs < count {
        return Err(
            format!("{num_envs} environments cannot be spread over {count} engines").into(),
        );
    }
    let sessions: Vec<RemoteEnv> = engines
        .iter()
        .enumerate()
        .map(|(k, engine)| {
            let share = num_envs / count + u32::from((k as u32) < num_envs % count);
            client.make(engine, task, share, &BTreeMap::new())
        })
        .collect::<Result<_, _>>()?;
    let batch: Vec<&RemoteEnv> = sessions.iter().collect();
    reset_batches(&batch, Some(0), None)?;
    let actions = vec![0.0; num_envs as usize * sessions[0].spec().action_space.dim()];
    step_batches(&batch, &actions)?;
    let (start, budget) = (Instant::now(), Duration::from_secs_f64(seconds));
    let mut rounds = 0u64;
    while start.elapsed() < budget {
        step_batches(&batch, &actions)?;
        rounds += 1;
    }
    let rate = (rounds * u64::from(num_envs)) as f64 / start.elapsed().as_secs_f64();
    println!(
        "{}",
        serde_json::json!({
            "task": task, "num_envs": num_envs, "engines": engines, "env_steps_per_s": rate,
        })
    );
    for session in &sessions {
        session.close()?;
    }
    Ok(())
}
