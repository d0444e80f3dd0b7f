//! Per-request cost against the number of open sessions, measured side by side in one run:
//! a bystander's `step` round trip (and the raw Zenoh `ping` beside it) with 0, 1 000 and
//! 10 000 other sessions open on the same engine; then closing a tenth of those sessions
//! one by one, and the time the engine takes to reclaim the other 9 000 when their client
//! vanishes.
//!
//! ```text
//! cargo bench -p ciflow-bridge --bench sessions
//! ```
//! Goal: the step's median within 10 % across the three counts, reclaiming under 1 s (the
//! engine first asks Zenoh for the vanished client's token again for up to 1 s; measured
//! 0.70 s in all).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::{self, MakeReply, MakeRequest, SessionRequest, keys};
use ciflow_bridge::zenoh::Wait;
use ciflow_bridge::{Client, EngineServer, Limits, NetworkOptions, Role, ServerOptions, query_all};

const ENDPOINT: &str = "tcp/127.0.0.1:27498";
const TASK: &str = "ciflow/LimitCycle-v0";
const COUNTS: [usize; 3] = [0, 1_000, 10_000];
const WARMUP: usize = 300;
const SAMPLES: usize = 3_000;

#[path = "../examples/support/timing.rs"]
mod timing;
use timing::{micros, time_calls};

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let largest = *COUNTS.last().expect("counts");
    let options = ServerOptions {
        name: Some("sessions-bench".into()),
        limits: Limits {
            max_sessions_per_client: largest as u32 + 1,
            ..Limits::DEFAULT
        },
        ..ServerOptions::default()
    };
    let engine = EngineServer::open(&NetworkOptions::endpoint(Role::Engine, ENDPOINT), options)?;
    let network = NetworkOptions::endpoint(Role::Client, ENDPOINT);
    let bystander = Client::open(&network)?;
    let crowd = Client::open(&network)?;
    let kwargs = BTreeMap::new();
    let env = bystander.make(engine.name(), TASK, 1, &kwargs)?;
    env.reset(Some(0), None)?;
    let ping_key = keys::ping(engine.name());
    let ping = || {
        let replies = bystander
            .zenoh_session()
            .get(&ping_key)
            .payload(vec![0u8; 64])
            .wait()
            .expect("ping sent");
        replies.recv().expect("ping answered");
    };

    println!(
        "== bystander latency against open sessions ({} CPUs)",
        num_cpus()
    );
    println!(
        "{:>9} {:>12} {:>10} {:>12}",
        "sessions", "step med µs", "p99 µs", "ping med µs"
    );
    // The crowd sends bare `make` requests, as a client written from the protocol page
    // would: a `RemoteEnv` would also declare a Zenoh querier per session, whose cost is
    // the client's, not the engine's.
    let make = protocol::encode(&MakeRequest {
        v: protocol::PROTOCOL_VERSION,
        instance: crowd.instance().to_owned(),
        task: TASK.into(),
        num_envs: 1,
        kwargs: kwargs.clone(),
        deadline_ms: None,
    });
    let make_key = keys::make(engine.name(), keys::ANONYMOUS);
    let mut open: Vec<MakeReply> = Vec::with_capacity(largest);
    let mut medians = Vec::new();
    let mut opening = Duration::ZERO;
    for count in COUNTS {
        let started = Instant::now();
        while open.len() < count {
            let reply = query_all(
                crowd.zenoh_session(),
                &make_key,
                make.clone(),
                Duration::from_secs(10),
            )?;
            let [Ok(made)] = reply.as_slice() else {
                panic!("make failed: {reply:?}");
            };
            open.push(protocol::decode_reply(made)?);
        }
        opening += started.elapsed();
        let (step_median, step_p99) = time_calls(WARMUP, SAMPLES, || {
            if env.step(&[0.0, 0.0]).expect("step").truncated {
                env.reset(None, None).expect("reset");
            }
        });
        let (step_median, step_p99) = (micros(step_median), micros(step_p99));
        let ping_median = micros(time_calls(WARMUP, SAMPLES, ping).0);
        println!("{count:>9} {step_median:>12.1} {step_p99:>10.1} {ping_median:>12.1}");
        medians.push(step_median);
    }
    for (count, median) in COUNTS.iter().zip(&medians).skip(1) {
        println!(
            "step median at {count} sessions / at 0: {:.2} (goal ≤ 1.10)",
            median / medians[0]
        );
    }
    println!(
        "opening {largest} sessions took {:.1} s ({:.0} µs each)",
        opening.as_secs_f64(),
        opening.as_secs_f64() * 1e6 / largest as f64
    );

    // A tenth of the crowd's sessions closed one by one, as a client would...
    let closing = Instant::now();
    let closed = largest / 10;
    for made in open.drain(..closed) {
        let close = protocol::encode(&SessionRequest {
            v: protocol::PROTOCOL_VERSION,
            token: made.token,
            index: 0,
        });
        let key = keys::session(engine.name(), keys::ANONYMOUS, &made.session, "close");
        let reply = query_all(crowd.zenoh_session(), &key, close, Duration::from_secs(10))?;
        assert!(matches!(reply.as_slice(), [Ok(_)]), "close succeeds");
    }
    println!(
        "closing {closed} sessions one by one: {:.1} s ({:.0} µs each)",
        closing.elapsed().as_secs_f64(),
        closing.elapsed().as_secs_f64() * 1e6 / closed as f64
    );
    // ...and the rest reclaimed when the crowd's client vanishes.
    let vanished = Instant::now();
    crowd.zenoh_session().close().wait()?;
    while engine.session_count() > 1 {
        std::thread::sleep(Duration::from_millis(1));
    }
    println!(
        "reclaiming {} sessions of a vanished client: {:.3} s (goal < 1 s)",
        open.len(),
        vanished.elapsed().as_secs_f64()
    );
    Ok(())
}

fn num_cpus() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}
