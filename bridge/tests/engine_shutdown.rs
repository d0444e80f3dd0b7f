//! A dropped engine has closed its Zenoh session when the drop returns. Its workers, its
//! Zenoh callbacks and the threads that look for vanished clients hold that session too:
//! the last of them used to close it a moment later, on its own thread, and if the program
//! was exiting meanwhile, Zenoh's statics were already gone (a panic at exit, in 6 of 20
//! runs of `shared_memory`).

mod common;

use std::net::{Ipv4Addr, TcpStream};

use ciflow_bridge::{Client, EngineServer, RemoteEnv};
use common::*;

/// An engine on `port` and a client's session of `num_envs` environments on it, reset.
fn engine_with_a_batch(port: u16, num_envs: u32) -> (EngineServer, Client, RemoteEnv) {
    let engine = start_engine(port);
    let client = connect(port);
    let env = client
        .make(engine.name(), FIXTURE_ID, num_envs, &no_kwargs())
        .expect("a batch session");
    env.reset_batch(Some(1), None).expect("reset");
    (engine, client, env)
}

/// Three times, since the old fault lost its race to the test only about half of the time.
#[test]
fn a_dropped_engine_has_closed_its_session() {
    for port in 27421..27424 {
        let (engine, _client, env) = engine_with_a_batch(port, 64);
        // A batch step is answered by a worker, not in Zenoh's callback.
        env.step_batch(&[0.1; 64]).expect("a step");
        assert!(
            TcpStream::connect((Ipv4Addr::LOCALHOST, port)).is_ok(),
            "the engine does not listen on its endpoint"
        );
        drop(engine);
        assert!(
            TcpStream::connect((Ipv4Addr::LOCALHOST, port)).is_err(),
            "the engine's session still listens after the engine was dropped"
        );
    }
}

/// A client that vanished sets a thread looking for it for about a second. That thread
/// used the engine's state during each look, and an engine dropped during one closed its
/// session on that thread, after the drop returned. Dropped at several moments of the
/// first looks, the engine has closed its session when the drop returns.
#[test]
fn a_dropped_engine_has_closed_its_session_while_it_looked_for_a_vanished_client() {
    for (port, delay_ms) in (27425..27430).zip([0, 5, 10, 20, 40]) {
        let (engine, client, env) = engine_with_a_batch(port, 4);
        // Gone without closing its session, as a client that crashed.
        std::mem::forget(env);
        drop(client);
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        drop(engine);
        assert!(
            TcpStream::connect((Ipv4Addr::LOCALHOST, port)).is_err(),
            "the engine's session still listens after the engine was dropped \
             {delay_ms} ms after its client vanished"
        );
    }
}
