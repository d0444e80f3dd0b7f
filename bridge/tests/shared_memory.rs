//! On one host, an engine hands large payloads (a batch's reply, an echo) to a client
//! through Zenoh's shared memory instead of copying them through the socket: the reply's
//! bytes arrive in a `/dev/shm` segment mapped into the client.
//! A client whose configuration turns shared memory off gets them over the network — the
//! negative control of the same check. A `step_batch` reply is written into shared memory
//! by the engine itself, not copied there by Zenoh: it arrives there even from an engine
//! whose Zenoh moves no reply into shared memory, and reaches a network-only client all
//! the same.

#![cfg(target_os = "linux")]

mod common;

use std::time::Duration;

use ciflow_bridge::protocol::{BatchStepReply, keys};
use ciflow_bridge::{EngineServer, NetworkOptions, RemoteEnv, Role, ServerOptions};
use common::*;
use zenoh::Wait;
use zenoh::bytes::ZBytes;

/// Larger than Zenoh's threshold for moving a message into shared memory (3 KiB) and
/// than one network batch (64 KiB), as a batch of 4096 environments' replies is.
const PAYLOAD_BYTES: usize = 256 * 1024;

/// Whether every byte of the engine's echo of a large ping lies in shared memory.
fn echo_arrives_in_shared_memory(client: &zenoh::Session, engine: &str) -> bool {
    let payload: Vec<u8> = (0..PAYLOAD_BYTES).map(|i| (i % 251) as u8).collect();
    let replies = client
        .get(keys::ping(engine))
        .payload(payload.clone())
        .timeout(Duration::from_secs(15))
        .wait()
        .expect("query sent");
    let reply = replies.recv().expect("the engine replies");
    let echo = reply.result().expect("a payload, not an error").payload();
    assert_eq!(*echo.to_bytes(), payload[..], "the echo is the payload");
    in_shared_memory(echo)
}

/// Whether every byte of `payload` lies in a shared-memory segment mapped here.
fn in_shared_memory(payload: &ZBytes) -> bool {
    let mappings = shared_memory_mappings();
    payload.slices().all(|slice| {
        let start = slice.as_ptr() as usize;
        let end = start + slice.len();
        mappings
            .iter()
            .any(|(m, _)| m.start <= start && end <= m.end)
    })
}

#[test]
fn large_payloads_between_engine_and_client_on_one_host_travel_in_shared_memory() {
    let port = 27403;
    let engine = start_engine(port);
    let options = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let config = options.to_zenoh_config(Role::Client).unwrap();
    let client = zenoh::open(config).wait().unwrap();
    // The first large message sets up the shared-memory pool, which takes a moment; the
    // messages of that moment go over the network.
    assert!(
        eventually(10.0, || echo_arrives_in_shared_memory(
            &client,
            engine.name()
        )),
        "a large reply to a client on the engine's host never arrived in shared memory"
    );

    let mut config = options.to_zenoh_config(Role::Client).unwrap();
    config
        .insert_json5("transport/shared_memory/enabled", "false")
        .unwrap();
    let network_only = zenoh::open(config).wait().unwrap();
    for _ in 0..5 {
        assert!(
            !echo_arrives_in_shared_memory(&network_only, engine.name()),
            "a client with shared memory off got the reply in shared memory"
        );
    }
}

/// An engine on `port` with the fixture tasks, whose Zenoh moves queries and puts into
/// shared memory but no reply, from a pool of `pool_bytes` (Zenoh's default: 16 MiB).
fn start_engine_without_reply_copies(port: u16, pool_bytes: usize) -> EngineServer {
    let config = std::env::temp_dir().join(format!("ciflow-test-{port}-no-reply-shm.json5"));
    let optimization = format!(r#"{{ pool_size: {pool_bytes}, messages: ["put", "query"] }}"#);
    std::fs::write(
        &config,
        format!(
            "{{ transport: {{ shared_memory: {{ transport_optimization: {optimization} }} }} }}"
        ),
    )
    .unwrap();
    let mut network = NetworkOptions::endpoint(Role::Engine, &endpoint(port));
    network.config_file = Some(config.clone());
    let mut options = ServerOptions::default();
    options.tasks.push(fixture_task());
    options.tasks.push(long_keyed_fixture_task());
    options.name = Some(format!("test-{port}"));
    let engine = EngineServer::open(&network, options).expect("engine starts");
    std::fs::remove_file(&config).unwrap();
    engine
}

/// Environments of the batch: its reply (`2 · 8` bytes of observation, 8 of reward and 2
/// of flags each, 104 KiB) is well past Zenoh's threshold for shared memory.
const BATCH: u32 = 4096;

/// The bytes of the engine's `step_batch` reply to `actions`, sent by hand so that its
/// payload can be looked at, with whether they arrived in shared memory; for a client that
/// holds the contexts of reply `known_contexts`, if given.
fn step_batch_by_hand(
    env: &RemoteEnv,
    client: &zenoh::Session,
    actions: &[f64],
    known_contexts: Option<u64>,
) -> (Vec<u8>, bool) {
    let (key, request) = step_batch_request(env, actions, known_contexts);
    let replies = client
        .get(key)
        .payload(request)
        .timeout(Duration::from_secs(15))
        .wait()
        .expect("query sent");
    let reply = replies.recv().expect("the engine replies");
    let payload = reply.result().expect("a payload, not an error").payload();
    (payload.to_bytes().into_owned(), in_shared_memory(payload))
}

#[test]
fn the_engine_writes_batch_replies_into_shared_memory_itself() {
    let port = 27404;
    let engine = start_engine_without_reply_copies(port, 16 << 20);

    let client_options = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let client = zenoh::open(client_options.to_zenoh_config(Role::Client).unwrap())
        .wait()
        .unwrap();
    let mut network_only = client_options.to_zenoh_config(Role::Client).unwrap();
    network_only
        .insert_json5("transport/shared_memory/enabled", "false")
        .unwrap();
    let network_only = zenoh::open(network_only).wait().unwrap();

    // The same batch, seeds and actions, for a client on shared memory and one without.
    let by_shared_memory = ciflow_bridge::Client::with_session(client.clone()).unwrap();
    let by_network = ciflow_bridge::Client::with_session(network_only.clone()).unwrap();
    let make = |client: &ciflow_bridge::Client, task: &str| {
        let env = client
            .make(engine.name(), task, BATCH, &Default::default())
            .expect("a batch session");
        env.reset_batch(Some(7), None).expect("reset");
        env
    };
    let (env, twin) = (
        make(&by_shared_memory, FIXTURE_ID),
        make(&by_network, FIXTURE_ID),
    );
    // The pool is set up on the first large message; until then replies come on the heap.
    let mut step = 0;
    let mut arrived_shared = false;
    while !arrived_shared && step < 200 {
        step += 1;
        let actions: Vec<f64> = (0..BATCH)
            .map(|i| f64::from(i % 13) * 0.01 * f64::from(step))
            .collect();
        let (reply, shared) = step_batch_by_hand(&env, &client, &actions, None);
        let (twin_reply, twin_shared) = step_batch_by_hand(&twin, &network_only, &actions, None);
        assert!(
            !twin_shared,
            "a client with shared memory off got the reply in shared memory"
        );
        assert!(
            reply == twin_reply,
            "step {step}: the same reply either way"
        );
        let decoded: BatchStepReply = rmp_serde::from_slice(&reply).expect("a step_batch reply");
        assert_eq!(decoded.observations.0.len(), 2 * BATCH as usize);
        arrived_shared = shared;
        if !shared {
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    assert!(
        arrived_shared,
        "no batch reply arrived in shared memory in {step} steps"
    );

    // With the pool set up, a new session's replies are written in place from its first
    // step, the room for their info columns taken from the reset's keys; and a task whose
    // info key is longer than the reply's estimate per key has its replies written in
    // place from its second step, the room taken from the step before.
    let actions = vec![0.1; BATCH as usize];
    for (task, first_in_place) in [(FIXTURE_ID, 1), (LONG_KEYED_FIXTURE_ID, 2)] {
        let env = make(&by_shared_memory, task);
        for step in 1..=3 {
            let (reply, shared) = step_batch_by_hand(&env, &client, &actions, None);
            let decoded: BatchStepReply = rmp_serde::from_slice(&reply).expect("a reply");
            assert_eq!(decoded.info.len(), 1, "{task}: one info column");
            if step >= first_in_place {
                assert!(shared, "{task}: reply {step} of a new session was copied");
            }
        }
    }

    // The control: a large reply the engine does not write itself stays off shared memory,
    // so it was the engine, not Zenoh, that put the batch's there.
    for _ in 0..3 {
        assert!(
            !echo_arrives_in_shared_memory(&client, engine.name()),
            "Zenoh moved a reply into shared memory though its configuration says not to"
        );
    }
}

/// Whether each of 12 consecutive `step_batch` replies to a client that keeps the
/// contexts arrived in shared memory, with how many contexts it updated: a batch of
/// `BATCH` fixture environments (episodes of 5 steps, all ending at once) served by an
/// engine whose pool holds `pool_bytes`, counted from the first reply that arrives there
/// (before it, the pool is being set up). With `whole_at_autoresets`, the client asks for
/// whole observations at each step that autoresets (the one after episodes end): the
/// contexts it changed are reported by a whole reply, and again by the next update.
fn replies_in_shared_memory(
    port: u16,
    pool_bytes: usize,
    whole_at_autoresets: bool,
) -> Vec<(bool, usize)> {
    let engine = start_engine_without_reply_copies(port, pool_bytes);
    let options = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let session = zenoh::open(options.to_zenoh_config(Role::Client).unwrap())
        .wait()
        .unwrap();
    let client = ciflow_bridge::Client::with_session(session.clone()).unwrap();
    let env = client
        .make(engine.name(), FIXTURE_ID, BATCH, &Default::default())
        .expect("a batch session");
    env.reset_batch(Some(3), None).expect("reset");
    let actions = vec![0.1; BATCH as usize];
    let mut known = 0;
    let mut replies = Vec::new();
    let mut episodes_ended = false;
    for _ in 0..200 {
        if whole_at_autoresets && episodes_ended {
            step_batch_by_hand(&env, &session, &actions, None);
        }
        let (reply, shared) = step_batch_by_hand(&env, &session, &actions, Some(known));
        let decoded: BatchStepReply = rmp_serde::from_slice(&reply).expect("a step_batch reply");
        episodes_ended = decoded
            .terminated
            .iter()
            .chain(&decoded.truncated)
            .any(|&e| e != 0);
        let update = decoded.contexts.expect("a context update");
        known = update.epoch;
        if shared || !replies.is_empty() {
            replies.push((shared, update.envs.len()));
        }
        if replies.len() == 12 {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    replies
}

/// A reply reserves room for the contexts it will update, not for all of them: from a
/// pool too small for a reply with every context (157 KiB) and large enough for one with
/// none (104 KiB), only the replies at which every environment autoresets are on the
/// heap; from a pool that holds both, none is: the autoresets were counted before the
/// step, and the smaller buffers released before were reclaimed to make room for a larger
/// one.
#[test]
fn batch_replies_reserve_room_for_the_contexts_they_update() {
    let batch = BATCH as usize;
    let small = replies_in_shared_memory(27407, 128 << 10, false);
    assert_eq!(small.len(), 12, "no reply arrived in shared memory");
    for (step, &(shared, updated)) in small.iter().enumerate() {
        assert!(
            updated == 0 || updated == batch,
            "step {step}: {updated} updated"
        );
        assert_eq!(shared, updated == 0, "step {step}: {updated} updated");
    }
    assert!(small.iter().any(|&(_, updated)| updated == batch));

    let large = replies_in_shared_memory(27408, 256 << 10, false);
    assert_eq!(large.len(), 12, "no reply arrived in shared memory");
    for (step, &(shared, updated)) in large.iter().enumerate() {
        assert!(shared, "step {step}: {updated} updated, on the heap");
    }
    assert!(large.iter().any(|&(_, updated)| updated == batch));

    // The contexts that autoresets changed at a step whose reply was whole are counted
    // too: the update that reports them next has its room.
    let mixed = replies_in_shared_memory(27409, 256 << 10, true);
    assert_eq!(mixed.len(), 12, "no reply arrived in shared memory");
    for (step, &(shared, updated)) in mixed.iter().enumerate() {
        assert!(shared, "update {step}: {updated} updated, on the heap");
    }
    assert!(mixed.iter().any(|&(_, updated)| updated == batch));
}
