//! One vector environment over sessions on two engines behind a router
//! (`ciflow_bridge::vector`): the merged batch equals one session of as many environments
//! on one engine with the same seeds, through next-step autoresets, also with one row of
//! reset options per environment; an info key that one
//! engine does not report is NaN for its environments; bad input is refused before any
//! request, and an engine that disappears fails the step with its name instead of hanging.

mod common;

use ciflow_bridge::vector::{reset_batches, step_batches, step_batches_into};
use ciflow_bridge::{
    AccessPolicy, BatchSeeds, BatchStep, BatchStepOut, BridgeError, Client, EngineServer,
    NetworkOptions, RemoteEnv, Role, Router, ServerOptions,
};
use ciflow_envs::ResetOptions;
use common::*;

/// An engine serving the fixture behind the router at `router`, listening on `port`.
fn engine_behind(router: &str, port: u16, name: &str) -> EngineServer {
    let network = NetworkOptions {
        connect: vec![router.to_owned()],
        listen: vec![endpoint(port)],
        ..NetworkOptions::default()
    };
    let mut options = ServerOptions::default();
    options.tasks.push(fixture_task());
    options.name = Some(name.into());
    EngineServer::open(&network, options).expect("the engine starts")
}

fn make(client: &Client, engine: &str, n: u32) -> RemoteEnv {
    client.make(engine, "fixture", n, &no_kwargs()).unwrap()
}

fn assert_same_step(spread: &BatchStep, single: &BatchStep, step: usize) {
    assert_eq!(spread.observations, single.observations, "step {step}");
    assert_eq!(spread.rewards, single.rewards, "step {step}");
    assert_eq!(spread.terminated, single.terminated, "step {step}");
    assert_eq!(spread.truncated, single.truncated, "step {step}");
    assert_eq!(spread.info, single.info, "step {step}");
}

#[test]
fn a_batch_over_two_engines_equals_one_session_on_one_engine() {
    let router_endpoint = endpoint(27481);
    let _router = Router::open(
        &NetworkOptions::endpoint(Role::Router, &router_endpoint),
        &AccessPolicy::default(),
    )
    .expect("the router starts");
    let _a = engine_behind(&router_endpoint, 27482, "vector-a");
    let b = engine_behind(&router_endpoint, 27483, "vector-b");
    let client =
        Client::open(&NetworkOptions::endpoint(Role::Client, &router_endpoint)).expect("joins");
    assert!(
        eventually(10.0, || client.engine_info("vector-b").is_ok()),
        "the router routes to both engines"
    );

    let (on_a, on_b) = (make(&client, "vector-a", 3), make(&client, "vector-b", 2));
    let single = make(&client, "vector-a", 5);
    let spread = [&on_a, &on_b];

    let (observations, info) = reset_batches(&spread, Some(10), None).unwrap();
    assert_eq!(
        (observations, info),
        single.reset_batch(Some(10), None).unwrap(),
        "environment i gets seed 10 + i wherever it lives"
    );
    // Past the episode's end: every environment autoresets on the step after.
    for step in 0..EPISODE_STEPS as usize + 3 {
        let actions: Vec<f64> = (0..5).map(|i| 0.1 * (i + step) as f64 - 0.3).collect();
        let merged = step_batches(&spread, &actions).unwrap();
        assert_same_step(&merged, &single.step_batch(&actions).unwrap(), step);
    }

    // One seed per environment, wherever it lives; `None` continues that RNG.
    let each = |seeds: &[Option<u64>]| BatchSeeds::Each(seeds.to_vec());
    let seeds = [Some(14), Some(11), Some(12), Some(13), Some(10)];
    let spread_reset = reset_batches(&spread, each(&seeds), None).unwrap();
    assert_eq!(
        spread_reset,
        single.reset_batch(each(&seeds), None).unwrap()
    );
    let counted = single.reset_batch(Some(10), None).unwrap().0;
    let rows: Vec<&[f64]> = counted.chunks(2).collect();
    let listed: Vec<&[f64]> = spread_reset.0.chunks(2).collect();
    assert_eq!(listed, [rows[4], rows[1], rows[2], rows[3], rows[0]]);
    let wrong_count = reset_batches(&spread, each(&seeds[..4]), None).unwrap_err();
    assert!(
        matches!(wrong_count, BridgeError::InvalidArgument(_)),
        "{wrong_count}"
    );
    let refused = single.reset_batch(each(&seeds[..4]), None).unwrap_err();
    assert!(refused.to_string().contains("4 seeds for 5"), "{refused}");

    // One row of options per environment: each resets, and autoresets, with its own
    // context, wherever it lives.
    let contexts = [-0.8, -0.4, 0.0, 0.4, 0.8];
    let rows = Some(ResetOptions {
        context: Some(contexts.to_vec()),
        ..ResetOptions::default()
    });
    let context_of = |observations: &[f64]| -> Vec<f64> {
        observations
            .chunks(2)
            .map(|observation| observation[1])
            .collect()
    };
    let (observations, info) = reset_batches(&spread, Some(3), rows.clone()).unwrap();
    assert_eq!(context_of(&observations), contexts);
    assert_eq!(
        (observations, info),
        single.reset_batch(Some(3), rows).unwrap()
    );
    for step in 0..EPISODE_STEPS as usize + 1 {
        let merged = step_batches(&spread, &[0.1; 5]).unwrap();
        assert_same_step(&merged, &single.step_batch(&[0.1; 5]).unwrap(), step);
        assert_eq!(context_of(&merged.observations), contexts, "step {step}");
    }
    // Three rows for five environments: the first engine's three would pass for its own
    // rows, so the whole batch's count is checked before anything is sent.
    let three = Some(ResetOptions {
        context: Some(contexts[..3].to_vec()),
        ..ResetOptions::default()
    });
    for refused in [
        reset_batches(&spread, Some(3), three.clone()).unwrap_err(),
        single.reset_batch(Some(3), three).unwrap_err(),
    ] {
        assert!(
            refused
                .to_string()
                .contains("a batch of 5 environments takes 1"),
            "{refused}"
        );
    }

    // One engine's environments a step ahead: at their autoreset they report only
    // `reset`, the others only `distance`.
    let (observations, _) = reset_batches(&spread, Some(0), None).unwrap();
    assert_eq!(observations.len(), 5 * 2);
    on_b.step_batch(&[0.0; 2]).unwrap();
    for _ in 1..EPISODE_STEPS {
        step_batches(&spread, &[0.0; 5]).unwrap();
    }
    let merged = step_batches(&spread, &[0.0; 5]).unwrap();
    let nan_where = |values: &[f64]| values.iter().map(|v| v.is_nan()).collect::<Vec<_>>();
    assert_eq!(
        nan_where(&merged.info["reset"]),
        [true, true, true, false, false]
    );
    assert_eq!(
        nan_where(&merged.info["distance"]),
        [false, false, false, true, true]
    );
    assert_eq!(merged.truncated, [true, true, true, false, false]);

    // Refused before anything is sent.
    let wrong_length = step_batches(&spread, &[0.0; 4]).unwrap_err();
    assert!(
        matches!(wrong_length, BridgeError::InvalidArgument(_)),
        "{wrong_length}"
    );
    let (mut observations, mut rewards, mut flags) = ([0; 8 * 5 * 2], [0; 8 * 5], [0; 5]);
    let short = step_batches_into(
        &spread,
        &[0.0; 5],
        BatchStepOut {
            observations: &mut observations,
            rewards: &mut rewards,
            terminated: &mut flags,
            truncated: &mut [0; 4],
        },
    )
    .unwrap_err();
    assert!(
        short
            .to_string()
            .contains("4 flag bytes for 5 environments"),
        "{short}"
    );
    let none = step_batches(&[], &[]).unwrap_err();
    assert!(matches!(none, BridgeError::InvalidArgument(_)), "{none}");

    // An engine that disappears: the step fails naming it.
    drop(b);
    match step_batches(&spread, &[0.0; 5]).unwrap_err() {
        BridgeError::Engine { engine, source } => {
            assert_eq!(engine, "vector-b");
            assert!(
                matches!(
                    *source,
                    BridgeError::NoEngine { .. } | BridgeError::NoReply { .. }
                ),
                "{source}"
            );
        }
        other => panic!("expected the engine's failure, got {other}"),
    }
}
