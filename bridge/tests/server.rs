//! Engine and clients in one process but on separate Zenoh sessions over loopback TCP:
//! every operation, ownership, autoreset, telemetry, hostile input and reclaiming.

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use ciflow_bridge::protocol::{
    self, ByteBuf, ErrorCode, F64s, PerturbationKindMsg, PerturbationMsg, StepRequest, Telemetry,
    keys,
};
use ciflow_envs::ResetOptions;
use common::*;
use zenoh::Wait;

#[test]
fn every_operation_round_trips_with_gymnasium_seeding() {
    let engine = start_engine(27411);
    let client = connect(27411);
    let engines = client.discover().unwrap();
    let info = engines
        .iter()
        .find(|e| e.name == engine.name())
        .expect("engine discovered");
    assert!(info.tasks.iter().any(|t| t.spec.id == FIXTURE_ID));

    let env = client
        .make(engine.name(), FIXTURE_ID, 1, &no_kwargs())
        .unwrap();
    assert_eq!(env.spec().id, FIXTURE_ID);
    let (first, reset_info) = env.reset(Some(7), None).unwrap();
    assert_eq!(reset_info.get("reset"), Some(&1.0));
    let (again, _) = env.reset(Some(7), None).unwrap();
    assert_eq!(first, again, "same seed, same first observation");
    let (unseeded, _) = env.reset(None, None).unwrap();
    assert_ne!(first, unseeded, "the RNG continues after the seeded reset");

    let options = ResetOptions {
        context: Some(vec![0.25]),
        ..Default::default()
    };
    let (observation, _) = env.reset(Some(1), Some(options)).unwrap();
    assert_eq!(observation[1], 0.25);
    let expert = env.expert(0).unwrap();
    let step = env.step(&expert).unwrap();
    assert!(
        (step.observation[0] - 0.25).abs() < 1e-12,
        "expert reaches the context"
    );
    assert!(
        (step.time - 0.1).abs() < 1e-12,
        "one control period of simulated time"
    );
    assert!(step.info.contains_key("distance"));

    assert_eq!(env.control().set_context(0, &[-0.5]).unwrap(), step.time);
    assert_eq!(
        remote_code(env.control().set_context(0, &[3.0]).unwrap_err()),
        ErrorCode::OutOfBounds
    );
    let accepted = env
        .control()
        .perturb(
            0,
            PerturbationMsg {
                kind: PerturbationKindMsg::JointTorque { torque: vec![1.0] },
                start: None,
                duration: 0.2,
            },
        )
        .unwrap();
    assert_eq!(
        accepted, step.time,
        "a perturbation without start begins now"
    );

    let pixels = env.render(0, 64, 48).unwrap();
    assert_eq!(pixels.len(), 64 * 48 * 3);
    let second = env.render(0, 8, 8).unwrap();
    assert_eq!(second.len(), 8 * 8 * 3);

    assert_eq!(
        remote_code(env.step(&[f64::NAN]).unwrap_err()),
        ErrorCode::NotFinite
    );
    assert_eq!(
        remote_code(env.step(&[1.0, 2.0]).unwrap_err()),
        ErrorCode::WrongDimension
    );
    for _ in 1..EPISODE_STEPS {
        env.step(&[0.0]).unwrap();
    }
    assert_eq!(
        remote_code(env.step(&[0.0]).unwrap_err()),
        ErrorCode::NeedsReset
    );

    assert_eq!(engine.session_count(), 1);
    env.close().unwrap();
    env.close().unwrap();
    assert_eq!(engine.session_count(), 0);
    assert_eq!(
        remote_code(env.reset(None, None).unwrap_err()),
        ErrorCode::UnknownSession
    );
    assert_eq!(
        remote_code(
            client
                .make(engine.name(), "no-such-task", 1, &no_kwargs())
                .err()
                .unwrap()
        ),
        ErrorCode::UnknownTask
    );
}

#[test]
fn batch_step_uses_next_step_autoreset() {
    let engine = start_engine(27412);
    let client = connect(27412);
    let n = 3;
    let env = client
        .make(engine.name(), "fixture", n, &no_kwargs())
        .unwrap();
    let (observations, info) = env.reset_batch(Some(10), None).unwrap();
    assert_eq!(observations.len(), 2 * n as usize);
    assert_eq!(info["reset"], vec![1.0; n as usize]);
    // Environment i is seeded with 10 + i: the same as a single env seeded so.
    let single = client
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();
    let (one, _) = single.reset(Some(11), None).unwrap();
    assert_eq!(&observations[2..4], one.as_slice());

    assert_eq!(
        remote_code(env.step(&[0.0]).unwrap_err()),
        ErrorCode::InvalidRequest,
        "single-env `step` on a batch"
    );
    assert_eq!(
        remote_code(env.step_batch(&[0.0; 2]).unwrap_err()),
        ErrorCode::WrongDimension
    );

    let actions = vec![1.0; n as usize];
    for step in 1..=EPISODE_STEPS {
        let out = env.step_batch(&actions).unwrap();
        assert_eq!(out.truncated, vec![step == EPISODE_STEPS; n as usize]);
        assert_eq!(out.info["distance"].len(), n as usize);
    }
    // The next step resets every environment instead of stepping it.
    let out = env.step_batch(&actions).unwrap();
    assert_eq!(out.rewards, vec![0.0; n as usize]);
    assert_eq!(out.truncated, vec![false; n as usize]);
    assert_eq!(out.info["reset"], vec![1.0; n as usize]);
    let out = env.step_batch(&actions).unwrap();
    assert!(!out.info.contains_key("reset"), "a normal step again");
    assert!(out.info["distance"].iter().all(|d| d.is_finite()));
}

#[test]
fn a_foreign_client_cannot_control_a_session() {
    let engine = start_engine(27413);
    let owner = connect(27413);
    let env = owner
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();
    env.reset(Some(0), None).unwrap();

    let intruder = connect(27413);
    let key = keys::session(engine.name(), keys::ANONYMOUS, env.session_id(), "step");
    for token in [vec![], vec![0u8; 16], env.token()[..15].to_vec()] {
        let request = StepRequest {
            v: protocol::PROTOCOL_VERSION,
            token: ByteBuf::from(token),
            action: F64s(vec![1.0]),
        };
        let error =
            raw_query(intruder.zenoh_session(), &key, protocol::encode(&request)).unwrap_err();
        assert_eq!(error.code, ErrorCode::Forbidden);
    }
    // The owner's session is untouched: still at step 0 of its episode.
    let step = env.step(&[0.0]).unwrap();
    assert!((step.time - 0.1).abs() < 1e-12);
}

#[test]
fn hostile_payloads_get_typed_errors_while_another_session_keeps_stepping() {
    let engine = start_engine(27414);
    let client = connect(27414);
    let steady = client
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();
    let victim = client
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();
    victim.reset(Some(0), None).unwrap();

    let stop = Arc::new(AtomicBool::new(false));
    let steps = Arc::new(AtomicU64::new(0));
    let stepper = {
        let (stop, steps) = (Arc::clone(&stop), Arc::clone(&steps));
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                steady.reset(None, None).unwrap();
                for _ in 0..EPISODE_STEPS {
                    steady.step(&[0.1]).unwrap();
                    steps.fetch_add(1, Ordering::Relaxed);
                }
            }
        })
    };

    let hostile = connect(27414);
    let zs = hostile.zenoh_session();
    let session_key =
        |op: &str| keys::session(engine.name(), keys::ANONYMOUS, victim.session_id(), op);
    let token = ByteBuf::from(victim.token().to_vec());
    let step = |action: Vec<f64>| {
        protocol::encode(&StepRequest {
            v: protocol::PROTOCOL_VERSION,
            token: token.clone(),
            action: F64s(action),
        })
    };
    let mut wrong_version = step(vec![0.0]);
    // The map's first entry is `v: 2` (positive fixint after the key "v").
    let v_at = wrong_version
        .windows(2)
        .position(|w| w == [0xa1, b'v'])
        .unwrap()
        + 2;
    wrong_version[v_at] = 9;
    let cases: Vec<(String, Vec<u8>, ErrorCode)> = vec![
        (
            session_key("step"),
            b"\xc1\xc1\xc1".to_vec(),
            ErrorCode::Malformed,
        ),
        (session_key("step"), vec![], ErrorCode::Malformed),
        (
            session_key("step"),
            protocol::encode(&vec![1u8, 2, 3]),
            ErrorCode::Malformed,
        ),
        (
            session_key("step"),
            wrong_version,
            ErrorCode::VersionMismatch,
        ),
        (
            session_key("step"),
            step(vec![f64::NAN]),
            ErrorCode::NotFinite,
        ),
        (
            session_key("step"),
            step(vec![f64::INFINITY]),
            ErrorCode::NotFinite,
        ),
        (
            session_key("step"),
            step(vec![0.0; 7]),
            ErrorCode::WrongDimension,
        ),
        (session_key("step"), step(vec![]), ErrorCode::WrongDimension),
        (
            session_key("step"),
            vec![0x80; protocol::MAX_REQUEST_BYTES + 1],
            ErrorCode::PayloadTooLarge,
        ),
        (
            session_key("fly"),
            step(vec![0.0]),
            ErrorCode::UnknownOperation,
        ),
        (
            keys::session(engine.name(), keys::ANONYMOUS, "0000000000000000", "step"),
            step(vec![0.0]),
            ErrorCode::UnknownSession,
        ),
        (
            keys::policy_act(engine.name(), "nobody"),
            vec![0x80],
            ErrorCode::Malformed,
        ),
        (
            keys::make(engine.name(), keys::ANONYMOUS),
            b"{\"v\":1}".to_vec(),
            ErrorCode::Malformed,
        ),
        (
            format!("{}/nothing/here", keys::engine(engine.name())),
            vec![],
            ErrorCode::UnknownOperation,
        ),
    ];
    for (key, payload, expected) in cases {
        let error = raw_query(zs, &key, payload).unwrap_err();
        assert_eq!(error.code, expected, "{key}: {}", error.message);
    }
    // A panic inside the task: an `internal` error, only that session is closed.
    let error = raw_query(zs, &session_key("step"), step(vec![PANIC_ACTION])).unwrap_err();
    assert_eq!(error.code, ErrorCode::Internal);
    assert_eq!(
        remote_code(victim.step(&[0.0]).unwrap_err()),
        ErrorCode::UnknownSession
    );

    let before = steps.load(Ordering::Relaxed);
    assert!(eventually(5.0, || steps.load(Ordering::Relaxed) > before + 10));
    assert_eq!(engine.session_count(), 1, "only the steady session is left");
    stop.store(true, Ordering::Relaxed);
    stepper.join().expect("the steady session never failed");
}

#[test]
fn sessions_of_a_vanished_client_are_reclaimed() {
    let engine = start_engine(27415);
    let survivor = connect(27415);
    let kept = survivor
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();

    let doomed = connect(27415);
    let orphans: Vec<_> = (0..3)
        .map(|_| {
            doomed
                .make(engine.name(), "fixture", 2, &no_kwargs())
                .unwrap()
        })
        .collect();
    assert_eq!(engine.session_count(), 4);
    // Vanish without closing anything: the Zenoh session ends, the token goes with it.
    doomed.zenoh_session().close().wait().unwrap();
    std::mem::forget(orphans);
    assert!(
        eventually(5.0, || engine.session_count() == 1),
        "orphans reclaimed"
    );
    kept.reset(Some(0), None).unwrap();
}

#[test]
fn make_needs_a_liveliness_token() {
    let engine = start_engine(27416);
    let client = connect(27416);
    let make = |instance: &str| {
        let request = protocol::MakeRequest {
            v: protocol::PROTOCOL_VERSION,
            instance: instance.into(),
            task: "fixture".into(),
            num_envs: 1,
            kwargs: no_kwargs(),
            deadline_ms: None,
        };
        raw_query(
            client.zenoh_session(),
            &keys::make(engine.name(), keys::ANONYMOUS),
            protocol::encode(&request),
        )
    };
    let error = make("nobody-declared-me").unwrap_err();
    assert_eq!(error.code, ErrorCode::NoLiveliness);
    assert_eq!(engine.session_count(), 0);

    // A token that reaches the engine only after the `make` does is still found: an empty
    // liveliness answer is asked again for a moment before it counts.
    let zsession = client.zenoh_session().clone();
    let declare_late = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(100));
        let alive = keys::client_alive(&keys::client(keys::ANONYMOUS, "declared-late"));
        zsession.liveliness().declare_token(alive).wait().unwrap()
    });
    let made = make("declared-late");
    let _token = declare_late.join().unwrap();
    assert!(made.is_ok(), "refused: {:?}", made.err().map(|e| e.message));
    assert_eq!(engine.session_count(), 1);
}

#[test]
fn a_token_that_comes_back_at_once_keeps_its_sessions() {
    let engine = start_engine(27438);
    let client = connect(27438);
    let zsession = client.zenoh_session();
    let alive = keys::client_alive(&keys::client(keys::ANONYMOUS, "flickering"));
    let declare = || zsession.liveliness().declare_token(&alive).wait().unwrap();
    let token = declare();
    let request = protocol::MakeRequest {
        v: protocol::PROTOCOL_VERSION,
        instance: "flickering".into(),
        task: "fixture".into(),
        num_envs: 1,
        kwargs: no_kwargs(),
        deadline_ms: None,
    };
    let made = raw_query(
        zsession,
        &keys::make(engine.name(), keys::ANONYMOUS),
        protocol::encode(&request),
    );
    assert!(made.is_ok(), "refused: {:?}", made.err().map(|e| e.message));
    assert_eq!(engine.session_count(), 1);

    // The engine hears the token deleted, then declared again: a reconnection, or a
    // route rebuilt. The client never went away, so its session stays.
    drop(token);
    let token = declare();
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(
        engine.session_count(),
        1,
        "a client still alive lost its session"
    );

    // Negative control: a token that stays away takes the session with it.
    drop(token);
    assert!(
        eventually(5.0, || engine.session_count() == 0),
        "the vanished client's session was never reclaimed"
    );
}

#[test]
fn telemetry_flows_while_a_viewer_subscribes() {
    let engine = start_engine(27417);
    let client = connect(27417);
    let env = client
        .make(engine.name(), "fixture", 1, &no_kwargs())
        .unwrap();
    env.reset(
        Some(3),
        Some(ResetOptions {
            context: Some(vec![0.5]),
            ..Default::default()
        }),
    )
    .unwrap();

    let viewer = connect(27417);
    let samples = viewer
        .zenoh_session()
        .declare_subscriber(keys::session(
            engine.name(),
            keys::ANONYMOUS,
            env.session_id(),
            "telemetry",
        ))
        .wait()
        .unwrap();
    let mut received = None;
    assert!(eventually(5.0, || {
        if env.step(&[0.0]).is_err() {
            let options = ResetOptions {
                context: Some(vec![0.5]),
                ..Default::default()
            };
            env.reset(None, Some(options)).unwrap();
        }
        received = samples.try_recv().unwrap();
        received.is_some()
    }));
    let telemetry: Telemetry =
        protocol::decode_reply(&received.unwrap().payload().to_bytes()).unwrap();
    assert_eq!(telemetry.session, env.session_id());
    assert_eq!(telemetry.context.0, vec![0.5]);
    assert_eq!(telemetry.state.0.len(), 1);
    assert_eq!(telemetry.command.0, vec![0.0]);
}

/// The environments of a batch record no trail (an episode's positions, which outweigh
/// the rest of an environment), so their frames draw none; a session of one environment
/// draws its trail, in the planar tasks' blue.
#[test]
fn only_a_single_environment_draws_its_trail() {
    let engine = start_engine(27418);
    let client = connect(27418);
    let trail_pixels = |num_envs: u32| {
        let env = client
            .make(
                engine.name(),
                "ciflow/LimitCycle-v0",
                num_envs,
                &no_kwargs(),
            )
            .unwrap();
        env.reset_batch(Some(0), None).unwrap();
        for _ in 0..100 {
            let actions: Vec<f64> = (0..num_envs).flat_map(|i| env.expert(i).unwrap()).collect();
            env.step_batch(&actions).unwrap();
        }
        let frame = env.render(0, 160, 160).unwrap();
        frame
            .chunks_exact(3)
            .filter(|pixel| *pixel == ciflow_envs::raster::BLUE)
            .count()
    };
    assert!(trail_pixels(1) > 50, "a single environment draws its trail");
    assert_eq!(trail_pixels(2), 0, "a batch's environment draws none");
}

/// The default engine of a task is the first reachable one serving it, by Gymnasium id
/// or short name; none serves a task nobody registered.
#[test]
fn the_first_engine_serving_a_task_is_found_by_id_or_name() {
    let engine = start_engine(27420);
    let client = connect(27420);
    let name = Some(engine.name().to_owned());
    assert_eq!(client.first_engine_serving(Some(FIXTURE_ID)).unwrap(), name);
    assert_eq!(
        client.first_engine_serving(Some("limit-cycle")).unwrap(),
        name
    );
    assert_eq!(client.first_engine_serving(None).unwrap(), name);
    assert_eq!(
        client
            .first_engine_serving(Some("ciflow/NoSuch-v0"))
            .unwrap(),
        None
    );
}
