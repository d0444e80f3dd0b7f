//! A dropped engine has closed its Zenoh session when the drop returns. Its workers hold
//! that session too: the last of them used to close it a moment later, on its own thread,
//! and if the program was exiting meanwhile, Zenoh's statics were already gone (a panic at
//! exit, in 6 of 20 runs of `shared_memory`).

mod common;

use std::net::{Ipv4Addr, TcpStream};

use common::*;

/// Three times, since the old fault lost its race to the test only about half of the time.
#[test]
fn a_dropped_engine_has_closed_its_session() {
    for port in 27421..27424 {
        let engine = start_engine(port);
        let client = connect(port);
        let env = client
            .make(engine.name(), FIXTURE_ID, 64, &no_kwargs())
            .expect("a batch session");
        env.reset_batch(Some(1), None).expect("reset");
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
