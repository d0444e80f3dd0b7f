//! Round-trip benchmark, everything measured side by side in one run against one engine:
//!
//! 1. raw Zenoh query round trip (`…/ping` echoes the payload; same size as a step);
//! 2. single-environment `step` round trip of a 2-D task through [`RemoteEnv::step`];
//! 3. raw round trips of large payloads, and the batched stepping throughput
//!    (env-steps/s) of `step_batch` for several batch sizes, each from a client on the
//!    engine's host configured as every client is by default (its requests through the
//!    socket, the engine's replies through Zenoh's shared memory) and from one whose
//!    configuration turns shared memory off (the network path), as ratios to two references
//!    measured in the same round: one environment alone on one thread, times the cores
//!    (what the engine cannot beat), and the same environments stepped as a batch in
//!    this process on every core, in lockstep (what serving adds to the stepping itself;
//!    the free-running figure, each core never waiting for the others, beside it).
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example roundtrip -- [ENDPOINT] [ENGINE]
//! ```
//! Without arguments it starts an engine in this process on its own Zenoh session
//! (loopback TCP, like a separate process); `bench/roundtrip.sh` runs it against
//! `ciflow serve` instead.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::keys;
use ciflow_bridge::zenoh::Wait;
use ciflow_bridge::zenoh::query::ConsolidationMode;
use ciflow_bridge::{Client, EngineServer, Limits, NetworkOptions, Role, ServerOptions};

#[path = "support/in_process.rs"]
mod in_process;
#[path = "support/timing.rs"]
mod timing;
use in_process::{Pace, in_process_rate};
use timing::{micros, time_calls};

const TASK: &str = "ciflow/LimitCycle-v0";
/// The 2-D tasks whose batched stepping has the 1M env-steps/s target.
const BATCHED_TASKS: [&str; 2] = ["ciflow/LimitCycle-v0", "ciflow/Obstacle-v0"];
const WARMUP: usize = 500;
const SAMPLES: usize = 5000;
const BATCH_SIZES: [u32; 5] = [1024, 4096, 16384, 65536, 262144];
/// Echoed payloads of the raw large-payload round trips: a batched reply of 4 096 obstacle
/// environments, and 4 MiB.
const LARGE_PAYLOADS: [usize; 2] = [565 * 1024, 4 << 20];
/// Steps of every batched measurement before its clock starts, served and in process.
const UNTIMED_STEPS: usize = 1;
/// Rounds of every batched measurement (see [`batched_rates`]).
const BATCH_ROUNDS: usize = 3;
/// Room for the largest batch (the default limit is 65 536 environments per session);
/// `bench/roundtrip.sh` gives `ciflow serve` the same flags.
const LIMITS: Limits = Limits {
    max_envs_per_session: 262_144,
    max_envs_per_client: 524_288,
    ..Limits::DEFAULT
};

/// Env-steps per second of one environment of the task alone on this thread.
fn alone_rate(task: &str) -> Result<f64, Box<dyn std::error::Error + Send + Sync>> {
    in_process_rate(task, 1, 1, (0, 200_000), Pace::Lockstep)
}

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (endpoint, _local_engine) = match args.first() {
        Some(endpoint) => (endpoint.clone(), None),
        None => {
            let endpoint = "tcp/127.0.0.1:27499".to_owned();
            let options = ServerOptions {
                name: Some("bench".into()),
                limits: LIMITS,
                ..ServerOptions::default()
            };
            let engine =
                EngineServer::open(&NetworkOptions::endpoint(Role::Engine, &endpoint), options)?;
            (endpoint, Some(engine))
        }
    };
    let client = Client::open(&NetworkOptions::endpoint(Role::Client, &endpoint))?;
    let engine = match args.get(1) {
        Some(name) => name.clone(),
        None => client
            .first_engine_serving(Some(TASK))?
            .ok_or("no engine serves the 2-D task")?,
    };

    let env = client.make(&engine, TASK, 1, &BTreeMap::new())?;
    env.reset(Some(0), None)?;
    let action = env.expert(0)?;
    let step_payload = ciflow_bridge::protocol::encode(&ciflow_bridge::protocol::StepRequest {
        v: ciflow_bridge::protocol::PROTOCOL_VERSION,
        token: ciflow_bridge::protocol::ByteBuf::from(env.token().to_vec()),
        action: ciflow_bridge::protocol::F64s(action.clone()),
    });
    let ping = client
        .zenoh_session()
        .declare_querier(keys::ping(&engine))
        .consolidation(ConsolidationMode::None)
        .wait()?;
    let mut raw = || {
        let replies = ping
            .get()
            .payload(step_payload.clone())
            .wait()
            .expect("ping");
        replies.recv().expect("ping reply");
    };
    let mut step = || {
        if env
            .step(&action)
            .map(|s| s.terminated || s.truncated)
            .unwrap_or(true)
        {
            env.reset(None, None).expect("reset");
        }
    };
    // Interleave the two measurements so that both see the same machine load.
    let (mut raw_runs, mut step_runs) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        raw_runs.push(time_calls(WARMUP, SAMPLES, &mut raw));
        step_runs.push(time_calls(WARMUP, SAMPLES, &mut step));
    }
    let (raw_median, raw_p99) = best_run(&raw_runs);
    let (step_median, step_p99) = best_run(&step_runs);
    println!("round trip ({TASK}, {SAMPLES} samples, best of 3 interleaved runs)");
    println!(
        "  raw Zenoh query (ping)   median {:7.1} µs   p99 {:7.1} µs",
        micros(raw_median),
        micros(raw_p99)
    );
    println!(
        "  Rust RemoteEnv::step     median {:7.1} µs   p99 {:7.1} µs",
        micros(step_median),
        micros(step_p99)
    );
    println!(
        "  ratio step / raw         median {:7.2}x     p99 {:7.2}x   (target ≤ 1.1x)",
        step_median.as_secs_f64() / raw_median.as_secs_f64(),
        step_p99.as_secs_f64() / raw_p99.as_secs_f64()
    );

    let network_only = network_only_client(&endpoint)?;
    let clients = [
        ("replies by shared memory", &client),
        ("network", &network_only),
    ];
    large_payload_round_trips(&clients, &engine)?;
    for task in BATCHED_TASKS {
        batched_rates(&clients, &engine, task)?;
    }
    Ok(())
}

/// A client of `endpoint` whose Zenoh configuration file turns shared memory off, so its
/// payloads cross the loopback socket as they would cross a network.
fn network_only_client(endpoint: &str) -> Result<Client, Box<dyn std::error::Error + Send + Sync>> {
    let path = std::env::temp_dir().join(format!(
        "ciflow-roundtrip-network-only-{}.json5",
        std::process::id()
    ));
    std::fs::write(
        &path,
        format!(
            "{{ mode: \"client\", connect: {{ endpoints: [\"{endpoint}\"] }},\n  \
             scouting: {{ multicast: {{ enabled: false }} }},\n  \
             transport: {{ shared_memory: {{ enabled: false }} }} }}\n"
        ),
    )?;
    let client = Client::open(&NetworkOptions {
        config_file: Some(path.clone()),
        ..NetworkOptions::default()
    });
    std::fs::remove_file(&path)?;
    Ok(client?)
}

/// Raw round trips of [`LARGE_PAYLOADS`] (the engine echoes them) from each of `clients`:
/// the best median of three interleaved runs.
fn large_payload_round_trips(
    clients: &[(&str, &Client)],
    engine: &str,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    println!("raw Zenoh query of a large payload, echoed (best median of 3 interleaved runs)");
    for bytes in LARGE_PAYLOADS {
        let payload = vec![7u8; bytes];
        let queriers = clients
            .iter()
            .map(|(_, client)| {
                client
                    .zenoh_session()
                    .declare_querier(keys::ping(engine))
                    .consolidation(ConsolidationMode::None)
                    .wait()
            })
            .collect::<Result<Vec<_>, _>>()?;
        let samples = if bytes > 1 << 20 { 20 } else { 100 };
        let mut runs = vec![Vec::new(); queriers.len()];
        for _ in 0..3 {
            for (querier, runs) in queriers.iter().zip(&mut runs) {
                runs.push(time_calls(2, samples, || {
                    let replies = querier.get().payload(payload.clone()).wait();
                    replies.expect("ping").recv().expect("ping reply");
                }));
            }
        }
        let medians: Vec<String> = runs
            .iter()
            .zip(clients)
            .map(|(runs, (name, _))| format!("{name} {:8.2} ms", micros(best_run(runs).0) / 1e3))
            .collect();
        println!(
            "  {:>5} KiB each way: {}",
            bytes / 1024,
            medians.join("   ")
        );
    }
    Ok(())
}

/// Batched env-steps per second of `task` for each of [`BATCH_SIZES`], from each of
/// `clients` (named), in [`BATCH_ROUNDS`] rounds that each measure the task alone again
/// first: the machine's load drifts, so a ratio is taken within one round and the median
/// over the rounds is printed with its range.
fn batched_rates(
    clients: &[(&str, &Client)],
    engine: &str,
    task: &str,
) -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "batched stepping ({task}, step_batch, next-step autoreset; {BATCH_ROUNDS} rounds: median (range))"
    );
    println!(
        "  reference: the task called directly, one thread, no network: {:.0} env-steps/s \
         (4096 environments in turn: {:.0})",
        alone_rate(task)?,
        in_process_rate(
            task,
            4096,
            1,
            (UNTIMED_STEPS, requests_per_measurement(4096)),
            Pace::Lockstep
        )?
    );
    println!(
        "  ratio: served / ({threads} threads x one environment alone); in process: served / the \
         same environments stepped as a batch in process on {threads} threads, every step of all \
         of them before the next (free-running: each thread its share all the steps through, \
         never waiting for the others, which bounds any synchronous batch); all measured in the \
         same round"
    );
    for n in BATCH_SIZES {
        let batches = clients
            .iter()
            .map(|(_, client)| client.make(engine, task, n, &BTreeMap::new()))
            .collect::<Result<Vec<_>, ciflow_bridge::BridgeError>>()?;
        let actions = vec![0.0; n as usize * batches[0].spec().action_space.dim()];
        let mut rates = vec![Vec::new(); batches.len()];
        let mut ratios = vec![Vec::new(); batches.len()];
        let mut in_process_ratios = vec![Vec::new(); batches.len()];
        let mut free_running_ratios = vec![Vec::new(); batches.len()];
        for round in 0..BATCH_ROUNDS {
            let alone = alone_rate(task)?;
            // The steps of the served measurement.
            let steps = (UNTIMED_STEPS, requests_per_measurement(n as usize));
            let in_process = in_process_rate(task, n as usize, threads, steps, Pace::Lockstep)?;
            let free_running =
                in_process_rate(task, n as usize, threads, steps, Pace::FreeRunning)?;
            // The clients take turns going first, so what the first measurement of a round
            // pays (caches the reference left cold) is not always the same client's.
            let mut order: Vec<usize> = (0..batches.len()).collect();
            order.rotate_left(round % batches.len());
            for k in order {
                // From the reset the in-process reference starts from, so both step the
                // same stretch of the same episodes.
                batches[k].reset_batch(Some(0), None)?;
                let rate = served_rate(&batches[k], &actions)?;
                rates[k].push(rate);
                ratios[k].push(rate / (threads as f64 * alone));
                in_process_ratios[k].push(rate / in_process);
                free_running_ratios[k].push(rate / free_running);
            }
        }
        let columns: Vec<String> = clients
            .iter()
            .zip(
                rates
                    .iter_mut()
                    .zip(&mut ratios)
                    .zip(in_process_ratios.iter_mut().zip(&mut free_running_ratios)),
            )
            .map(|((name, _), ((rates, ratios), (in_process_ratios, free_running_ratios)))| {
                let (rate, _) = median_and_range(rates);
                let (ratio, (low, high)) = median_and_range(ratios);
                let (in_process, (in_low, in_high)) = median_and_range(in_process_ratios);
                let (free_running, _) = median_and_range(free_running_ratios);
                let request_ms = 1e3 * n as f64 / rate;
                format!(
                    "{name} {rate:>9.0}/s ({request_ms:.2} ms) ratio {ratio:.2} ({low:.2}-{high:.2}) \
                     in process {in_process:.2} ({in_low:.2}-{in_high:.2}, free-running {free_running:.2})"
                )
            })
            .collect();
        println!("  num_envs {n:>7}: {}", columns.join("   "));
        for batch in batches {
            batch.close()?;
        }
    }
    Ok(())
}

/// Env-steps per second of `batch` stepped with `actions`, after [`UNTIMED_STEPS`].
fn served_rate(
    batch: &ciflow_bridge::RemoteEnv,
    actions: &[f64],
) -> Result<f64, ciflow_bridge::BridgeError> {
    let n = batch.num_envs() as usize;
    for _ in 0..UNTIMED_STEPS {
        batch.step_batch(actions)?;
    }
    let requests = requests_per_measurement(n);
    let start = Instant::now();
    for _ in 0..requests {
        batch.step_batch(actions)?;
    }
    Ok((requests * n) as f64 / start.elapsed().as_secs_f64())
}

/// Timed `step_batch` requests of `num_envs` environments in one measurement.
fn requests_per_measurement(num_envs: usize) -> usize {
    (1_000_000 / num_envs).clamp(3, 100)
}

/// The `(median, p99)` of the run with the lowest median.
fn best_run(runs: &[(Duration, Duration)]) -> (Duration, Duration) {
    *runs
        .iter()
        .min_by_key(|run| run.0)
        .expect("at least one run")
}

/// The median of `values` (sorted in place) and their range.
fn median_and_range(values: &mut [f64]) -> (f64, (f64, f64)) {
    values.sort_by(f64::total_cmp);
    let median = values[values.len() / 2];
    (median, (values[0], values[values.len() - 1]))
}
