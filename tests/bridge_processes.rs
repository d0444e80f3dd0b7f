//! `ciflow serve` in its own process, driven by clients in other processes over Zenoh:
//! every registered task, a client killed mid-episode, hostile payloads next to a
//! session that keeps stepping, and the engine's threads scheduled as batch threads.

mod common;

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::{self, ByteBuf, ErrorCode, F64s, StepRequest, keys};
use ciflow_bridge::query_all;
use common::{Process, code, connect, serve};

/// The 2-D task used where any task will do.
const LIMIT_CYCLE: &str = "ciflow/LimitCycle-v0";

#[test]
fn serve_hosts_every_task_for_clients_in_other_processes() {
    let _server = serve(27431, "every-task", &[]);
    let client = connect(27431);
    let engines = client.discover().unwrap();
    let engine = engines
        .iter()
        .find(|e| e.name == "every-task")
        .expect("discovered");
    let tasks: Vec<&str> = ciflow_envs::tasks().iter().map(|t| t.id).collect();
    assert_eq!(
        tasks.len(),
        5,
        "limit cycle, obstacle avoidance, pouring, reach, LASA: {tasks:?}"
    );
    for task in tasks {
        let info = engine.tasks.iter().find(|t| t.spec.id == task);
        let info = info.unwrap_or_else(|| panic!("{task} is served"));
        let env = client
            .make(&engine.name, task, 1, &BTreeMap::new())
            .unwrap();
        assert_eq!(env.spec(), &info.spec);
        let (first, _) = env.reset(Some(11), None).unwrap();
        let (again, _) = env.reset(Some(11), None).unwrap();
        assert_eq!(first, again, "{task}: seeded resets agree");
        assert!(
            info.spec.observation_space.contains(&first),
            "{task}: first observation"
        );
        for step in 1..=10 {
            let action = env.expert(0).unwrap();
            let out = env.step(&action).unwrap();
            assert!(out.observation.iter().all(|x| x.is_finite()), "{task}");
            assert!((out.time - step as f64 * info.spec.control_dt).abs() < 1e-9);
            if out.terminated || out.truncated {
                break;
            }
        }
        let pixels = env.render(0, 32, 24).unwrap();
        assert_eq!(pixels.len(), 32 * 24 * 3, "{task}: frame size");
        env.close().unwrap();

        let batch = client
            .make(&engine.name, task, 16, &BTreeMap::new())
            .unwrap();
        let (observations, _) = batch.reset_batch(Some(0), None).unwrap();
        let obs_dim = info.spec.observation_space.dim();
        assert_eq!(observations.len(), 16 * obs_dim);
        let actions = vec![0.0; 16 * info.spec.action_space.dim()];
        let out = batch.step_batch(&actions).unwrap();
        assert_eq!(out.observations.len(), 16 * obs_dim);
        assert_eq!(out.rewards.len(), 16);
    }
}

/// Run as a child by `killed_client_sessions_are_reclaimed`: makes two sessions, prints
/// `<session> <token-hex>` for each, then waits to be killed.
#[test]
#[ignore = "child process of killed_client_sessions_are_reclaimed"]
fn child_client_process() {
    let port: u16 = std::env::var("CIFLOW_TEST_PORT").unwrap().parse().unwrap();
    let engine = std::env::var("CIFLOW_TEST_ENGINE").unwrap();
    let client = connect(port);
    let sessions: Vec<_> = (0..2)
        .map(|_| {
            client
                .make(&engine, LIMIT_CYCLE, 1, &BTreeMap::new())
                .unwrap()
        })
        .collect();
    for env in &sessions {
        env.reset(Some(0), None).unwrap();
        env.step(&env.expert(0).unwrap()).unwrap();
        let token: String = env.token().iter().map(|b| format!("{b:02x}")).collect();
        println!("SESSION {} {token}", env.session_id());
    }
    std::thread::sleep(Duration::from_secs(120));
}

#[test]
fn killed_client_sessions_are_reclaimed() {
    let _server = serve(27432, "reclaim", &[]);
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--ignored",
            "--exact",
            "child_client_process",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("CIFLOW_TEST_PORT", "27432")
        .env("CIFLOW_TEST_ENGINE", "reclaim")
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn the child client");
    let stdout = BufReader::new(child.stdout.take().unwrap());
    let sessions: Vec<(String, Vec<u8>)> = stdout
        .lines()
        .map(|line| line.unwrap())
        // libtest may print `test child_client_process ... ` in front of the first line.
        .filter_map(|line| line.split_once("SESSION ").map(|(_, rest)| rest.to_owned()))
        .take(2)
        .map(|line| {
            let (session, token) = line.split_once(' ').unwrap();
            let token = (0..token.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&token[i..i + 2], 16).unwrap())
                .collect();
            (session.to_owned(), token)
        })
        .collect();
    assert_eq!(sessions.len(), 2);
    let mut child = Process(child);

    let observer = connect(27432);
    let reset = |session: &str, token: &[u8]| {
        let request = protocol::ResetRequest {
            v: protocol::PROTOCOL_VERSION,
            token: ByteBuf::from(token.to_vec()),
            seed: Some(1),
            seeds: None,
            options: None,
        };
        let key = keys::session("reclaim", keys::ANONYMOUS, session, "reset");
        let mut replies = query_all(
            observer.zenoh_session(),
            &key,
            protocol::encode(&request),
            Duration::from_secs(5),
        )
        .unwrap();
        assert_eq!(replies.len(), 1);
        replies.pop().unwrap()
    };
    for (session, token) in &sessions {
        assert!(
            reset(session, token).is_ok(),
            "the live child's session answers"
        );
    }
    child.0.kill().unwrap();
    child.0.wait().unwrap();
    let killed = Instant::now();
    for (session, token) in &sessions {
        let reclaimed = loop {
            match reset(session, token) {
                Err(error) if error.code == ErrorCode::UnknownSession => break true,
                _ if killed.elapsed() > Duration::from_secs(10) => break false,
                _ => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        assert!(reclaimed, "session {session} reclaimed within 10 s");
    }
    eprintln!("sessions reclaimed {:?} after the kill", killed.elapsed());
}

#[test]
fn hostile_payloads_get_errors_while_a_parallel_session_keeps_stepping() {
    let _server = serve(27433, "hostile", &[]);
    let client = Arc::new(connect(27433));
    let steady = client
        .make("hostile", LIMIT_CYCLE, 1, &BTreeMap::new())
        .unwrap();
    let target = client
        .make("hostile", LIMIT_CYCLE, 1, &BTreeMap::new())
        .unwrap();
    let action_dim = target.spec().action_space.dim();
    let stop = Arc::new(AtomicBool::new(false));
    let steps = Arc::new(AtomicU64::new(0));
    let stepper = {
        let (stop, steps) = (Arc::clone(&stop), Arc::clone(&steps));
        std::thread::spawn(move || {
            steady.reset(Some(0), None).unwrap();
            while !stop.load(Ordering::Relaxed) {
                let out = steady.step(&steady.expert(0).unwrap()).unwrap();
                if out.terminated || out.truncated {
                    steady.reset(None, None).unwrap();
                }
                steps.fetch_add(1, Ordering::Relaxed);
            }
        })
    };

    let hostile = connect(27433);
    let key = |op: &str| keys::session("hostile", keys::ANONYMOUS, target.session_id(), op);
    let step = |token: Vec<u8>, action: Vec<f64>| {
        protocol::encode(&StepRequest {
            v: protocol::PROTOCOL_VERSION,
            token: ByteBuf::from(token),
            action: F64s(action),
        })
    };
    let token = target.token().to_vec();
    let cases = [
        (key("step"), b"\x92\x01".to_vec(), ErrorCode::Malformed),
        (key("step"), vec![0xc1; 64], ErrorCode::Malformed),
        (
            key("step"),
            step(token.clone(), vec![f64::NAN; action_dim]),
            ErrorCode::NotFinite,
        ),
        (
            key("step"),
            step(token.clone(), vec![0.0; action_dim + 3]),
            ErrorCode::WrongDimension,
        ),
        (
            key("step"),
            step(vec![1; 16], vec![0.0; action_dim]),
            ErrorCode::Forbidden,
        ),
        (
            key("step"),
            step(token.clone(), vec![0.0; action_dim]),
            ErrorCode::NeedsReset,
        ),
        (key("teleport"), vec![], ErrorCode::UnknownOperation),
        (
            key("step"),
            vec![0; protocol::MAX_REQUEST_BYTES + 8],
            ErrorCode::PayloadTooLarge,
        ),
        (
            keys::session("hostile", keys::ANONYMOUS, "ffffffffffffffff", "step"),
            vec![],
            ErrorCode::UnknownSession,
        ),
    ];
    for (key, payload, expected) in cases {
        let mut replies = query_all(
            hostile.zenoh_session(),
            &key,
            payload,
            Duration::from_secs(10),
        )
        .unwrap();
        assert_eq!(replies.len(), 1, "{key}: exactly one reply");
        let error = replies.pop().unwrap().unwrap_err();
        assert_eq!(error.code, expected, "{key}: {}", error.message);
    }
    assert_eq!(
        code(target.step(&vec![0.0; action_dim]).unwrap_err()),
        ErrorCode::NeedsReset
    );
    target.reset(Some(0), None).unwrap();

    let before = steps.load(Ordering::Relaxed);
    let deadline = Instant::now() + Duration::from_secs(5);
    while steps.load(Ordering::Relaxed) < before + 20 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(
        steps.load(Ordering::Relaxed) >= before + 20,
        "the parallel session kept stepping"
    );
    stop.store(true, Ordering::Relaxed);
    stepper.join().expect("the parallel session never failed");
}

/// Each thread of process `pid` with its scheduling policy (`/proc/<pid>/task/*/stat`,
/// field 41), e.g. `("rx-0", 3)`; 0 is Linux's normal policy, 3 `SCHED_BATCH`.
#[cfg(target_os = "linux")]
fn thread_policies(pid: u32) -> Vec<(String, u32)> {
    std::fs::read_dir(format!("/proc/{pid}/task"))
        .unwrap()
        // A thread that ended meanwhile has no `stat` left to read.
        .filter_map(|task| std::fs::read_to_string(task.unwrap().path().join("stat")).ok())
        .map(|stat| {
            // `pid (comm) state …`: the name may hold spaces and parentheses, the fields
            // after its closing one do not; the state is field 3, the policy field 41.
            let (head, fields) = stat.rsplit_once(')').unwrap();
            let name = head.split_once('(').unwrap().1.to_owned();
            let policy = fields
                .split_whitespace()
                .nth(41 - 3)
                .unwrap()
                .parse()
                .unwrap();
            (name, policy)
        })
        .collect()
}

/// `ciflow serve` runs every thread of the engine — Zenoh's, its workers, its stepping
/// pool — as a batch thread, so that the clients sharing its cores are not preempted
/// when it wakes (`ciflow_bridge::scheduling`).
#[cfg(target_os = "linux")]
#[test]
fn serve_runs_all_its_threads_as_batch_threads() {
    const SCHED_BATCH: u32 = 3;
    let server = serve(27434, "batch", &[]);
    // A batched step has the workers and the stepping pool started.
    let client = connect(27434);
    let env = client
        .make("batch", LIMIT_CYCLE, 600, &BTreeMap::new())
        .unwrap();
    env.reset_batch(Some(0), None).unwrap();
    env.step_batch(&vec![0.0; 600 * env.spec().action_space.dim()])
        .unwrap();
    let engine = thread_policies(server.0.id());
    assert!(engine.len() > 4, "the engine's threads: {engine:?}");
    // Zenoh gives its shared-memory watchdogs a real-time policy of its own.
    let others: Vec<_> = engine
        .iter()
        .filter(|(name, _)| !name.starts_with("Watchdog"))
        .collect();
    assert!(
        others.iter().all(|(_, policy)| *policy == SCHED_BATCH),
        "{engine:?}"
    );
    // Negative control: this test's own threads run under the normal policy, and the
    // same reading tells them apart.
    let own = thread_policies(std::process::id());
    assert!(own.iter().any(|(_, policy)| *policy == 0), "{own:?}");
}
