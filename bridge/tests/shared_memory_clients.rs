//! Clients send through the socket and only read the engine's shared memory, so they
//! leave no pool of theirs mapped in the engine however many come and go. Alone in its
//! test binary: it counts the pools mapped in its process, where other tests' engines
//! would map theirs.

#![cfg(target_os = "linux")]

mod common;

use std::collections::BTreeSet;

use ciflow_bridge::{NetworkOptions, Role};
use common::*;
use zenoh::Wait;

/// Zenoh's shared-memory pool for large messages (its default size): a process that sends
/// one sets it up, and every process that reads from it maps it.
const POOL_BYTES: usize = 16 << 20;

/// Environments of the batch: 4 096 actions of 8 bytes, past the 3 KiB from which Zenoh
/// sends a message through its pool when the sender has one, and a reply that is too.
const BATCH: u32 = 4096;

/// Zenoh shared-memory segments of a pool's size or more mapped here (each session that
/// reads a segment maps it once more: counted once).
fn pools_mapped() -> usize {
    let pools: BTreeSet<String> = shared_memory_mappings()
        .into_iter()
        .filter(|(range, _)| range.len() >= POOL_BYTES)
        .map(|(_, path)| path)
        .collect();
    pools.len()
}

/// Zenoh never unmaps a segment it has read from, so an engine would keep the pool of
/// every client that ever sent it a large request, and tmpfs keeps a pool's pages while
/// anyone maps it: on a host with 64 MiB of `/dev/shm` (Docker's default) the fourth
/// client could no longer open a session. Here the engine and three clients that come
/// and go share this process: however many clients came, the one pool mapped is the
/// engine's (none would mean its replies never went through shared memory).
#[test]
fn clients_come_and_go_without_leaving_a_pool_in_the_engine() {
    let port = 27406;
    let engine = start_engine(port);
    let options = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let actions = vec![0.1; BATCH as usize];
    for _ in 0..3 {
        let zenoh = zenoh::open(options.to_zenoh_config(Role::Client).unwrap())
            .wait()
            .unwrap();
        let client = ciflow_bridge::Client::with_session(zenoh.clone()).unwrap();
        let env = client
            .make(engine.name(), FIXTURE_ID, BATCH, &Default::default())
            .expect("a batch session");
        env.reset_batch(Some(3), None).expect("reset");
        for _ in 0..20 {
            env.step_batch(&actions).expect("a step");
        }
        drop((env, client));
        zenoh.close().wait().unwrap();
    }
    assert_eq!(pools_mapped(), 1, "only the engine's pool is mapped");
}
