//! A `step_batch` reply to a client that keeps its own copy of the contexts leaves them out
//! of the observations and carries only those that changed: the observations the client
//! rebuilds must be, bit for bit, those of the whole replies an engine sends a client that
//! asks for every observation in full — through autoresets (new contexts), a `context`
//! request mid-episode, and a reply the client never received.

mod common;

use ciflow_bridge::protocol::{BatchStepReply, ErrorCode, ErrorReply};
use ciflow_bridge::{BatchStep, Client, EngineServer, NetworkOptions, RemoteEnv, Role};
use common::*;
use zenoh::Wait;

/// Environments per session: more than one rayon chunk of the engine's stepping.
const ENVS: u32 = 300;

/// The reply to a `step_batch` sent by hand, with `known_contexts` as given.
fn step_by_hand(
    env: &RemoteEnv,
    zsession: &zenoh::Session,
    actions: &[f64],
    known_contexts: Option<u64>,
) -> Result<BatchStepReply, ErrorReply> {
    let (key, request) = step_batch_request(env, actions, known_contexts);
    let payload = raw_query(zsession, &key, request)?;
    Ok(rmp_serde::from_slice(&payload).expect("a step_batch reply"))
}

fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

/// `got` holds `expected` bit for bit; else the first place they differ.
fn assert_same(got: &[f64], expected: &[f64], what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}: length");
    if let Some(i) = (0..got.len()).find(|&i| got[i].to_bits() != expected[i].to_bits()) {
        panic!(
            "{what}: value {i} is {} where the whole reply has {}",
            got[i], expected[i]
        );
    }
}

fn actions(step: u32) -> Vec<f64> {
    (0..ENVS)
        .map(|i| f64::from(i % 7) * 0.03 - 0.05 * f64::from(step % 3))
        .collect()
}

/// An engine on `port`, and a client with the Zenoh session it talks through.
fn engine_and_client(port: u16) -> (EngineServer, zenoh::Session, Client) {
    let engine = start_engine(port);
    let options = NetworkOptions::endpoint(Role::Client, &endpoint(port));
    let zsession = zenoh::open(options.to_zenoh_config(Role::Client).unwrap())
        .wait()
        .unwrap();
    let client = Client::with_session(zsession.clone()).unwrap();
    (engine, zsession, client)
}

#[test]
fn observations_rebuilt_from_context_updates_are_the_whole_replies() {
    let (engine, zsession, client) = engine_and_client(27491);
    let make = || {
        let env = client
            .make(engine.name(), FIXTURE_ID, ENVS, &Default::default())
            .expect("a batch session");
        env.reset_batch(Some(11), None).expect("reset");
        env
    };
    // The same batch twice: one stepped as clients step it, one asked for whole replies.
    let (updated, whole) = (make(), make());
    let mut autoresets = 0;
    for step in 1..=4 * EPISODE_STEPS as u32 {
        if step == 3 {
            for env in [&updated, &whole] {
                env.control()
                    .set_context(17, &[0.625])
                    .expect("context set");
            }
        }
        if step == 7 {
            // A step whose reply the client never applies (as if it never arrived), with
            // a new context and the autoresets of the step after the first episodes end.
            for env in [&updated, &whole] {
                env.control()
                    .set_context(250, &[-0.375])
                    .expect("context set");
            }
            step_by_hand(&updated, &zsession, &actions(step), Some(0)).unwrap();
            step_by_hand(&whole, &zsession, &actions(step), None).unwrap();
            continue;
        }
        let got: BatchStep = updated.step_batch(&actions(step)).expect("a step");
        let expected = step_by_hand(&whole, &zsession, &actions(step), None).unwrap();
        assert!(
            expected.contexts.is_none(),
            "a whole reply carries no update"
        );
        assert_same(
            &got.observations,
            &expected.observations.0,
            &format!("step {step}: observations"),
        );
        assert_same(
            &got.rewards,
            &expected.rewards.0,
            &format!("step {step}: rewards"),
        );
        let flags = |f: &[bool]| f.iter().map(|&b| u8::from(b)).collect::<Vec<_>>();
        assert_eq!(
            flags(&got.truncated),
            expected.truncated.as_ref(),
            "step {step}"
        );
        assert!(
            got.info.keys().eq(expected.info.keys()),
            "step {step}: info keys"
        );
        for (key, values) in &got.info {
            assert_same(
                values,
                &expected.info[key].0,
                &format!("step {step}: info {key}"),
            );
        }
        autoresets += got.rewards.iter().filter(|r| **r == 0.0).count();
    }
    assert!(autoresets > 0, "the batch's episodes ended and restarted");
}

#[test]
fn a_reply_carries_the_contexts_that_changed_since_the_client_s_epoch() {
    let (engine, zsession, client) = engine_and_client(27492);
    let env = client
        .make(engine.name(), FIXTURE_ID, ENVS, &Default::default())
        .expect("a batch session");
    let (reset, _) = env.reset_batch(Some(3), None).expect("reset");
    let n = ENVS as usize;

    // A client that holds none gets every context, and observations without them.
    let first = step_by_hand(&env, &zsession, &actions(1), Some(0)).unwrap();
    let update = first.contexts.expect("an update");
    assert_eq!(update.envs, (0..ENVS).collect::<Vec<_>>());
    let contexts: Vec<f64> = reset.chunks_exact(2).map(|o| o[1]).collect();
    assert_eq!(
        bits(&update.values.0),
        bits(&contexts),
        "the reset's contexts"
    );
    assert_eq!(
        first.observations.0.len(),
        n,
        "one state value per environment"
    );

    // Then only what changed: nothing, then the one context set.
    let second = step_by_hand(&env, &zsession, &actions(2), Some(update.epoch)).unwrap();
    let unchanged = second.contexts.expect("an update");
    assert!(unchanged.envs.is_empty() && unchanged.epoch > update.epoch);
    env.control().set_context(42, &[0.5]).expect("context set");
    let third = step_by_hand(&env, &zsession, &actions(3), Some(unchanged.epoch)).unwrap();
    let changed = third.contexts.expect("an update");
    assert_eq!((changed.envs, changed.values.0), (vec![42], vec![0.5]));

    // An epoch the engine has not sent is refused.
    let error = step_by_hand(&env, &zsession, &actions(4), Some(changed.epoch + 1)).unwrap_err();
    assert_eq!(error.code, ErrorCode::InvalidRequest);
    assert!(
        error.message.contains("known_contexts"),
        "{}",
        error.message
    );
}
