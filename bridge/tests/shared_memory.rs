//! On one host, an engine and a client hand large payloads (a batch's actions, its
//! reply) to each other through Zenoh's shared memory instead of copying them through
//! the socket: the reply's bytes arrive in a `/dev/shm` segment mapped into the client.
//! A client whose configuration turns shared memory off gets them over the network — the
//! negative control of the same check.

#![cfg(target_os = "linux")]

mod common;

use std::ops::Range;
use std::time::Duration;

use ciflow_bridge::protocol::keys;
use ciflow_bridge::{NetworkOptions, Role};
use common::*;
use zenoh::Wait;

/// Larger than Zenoh's threshold for moving a message into shared memory (3 KiB) and
/// than one network batch (64 KiB), as a batch of 4096 environments' replies is.
const PAYLOAD_BYTES: usize = 256 * 1024;

/// Address ranges of this process's mappings of Zenoh's shared-memory segments.
fn shared_memory_mappings() -> Vec<Range<usize>> {
    let maps = std::fs::read_to_string("/proc/self/maps").expect("/proc/self/maps");
    maps.lines()
        .filter(|line| line.contains("/dev/shm/") && line.ends_with(".zenoh"))
        .map(|line| {
            let range = line.split_whitespace().next().expect("address range");
            let (start, end) = range.split_once('-').expect("start-end");
            let address = |hex: &str| usize::from_str_radix(hex, 16).expect("hex address");
            address(start)..address(end)
        })
        .collect()
}

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
    let mappings = shared_memory_mappings();
    echo.slices().all(|slice| {
        let start = slice.as_ptr() as usize;
        let end = start + slice.len();
        mappings.iter().any(|m| m.start <= start && end <= m.end)
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
