//! Property tests of what the engine reads: arbitrary bytes and arbitrary MessagePack
//! maps built from the protocol's own field names, sent to every operation. Whatever
//! arrives, the decoder never panics, every request gets exactly one reply — a success or
//! a typed error — and the engine keeps serving a session that behaves.

mod common;

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::time::Duration;

use ciflow_bridge::protocol::{
    self, ActRequest, BatchStepRequest, CheckpointMsg, ContextRequest, ErrorCode, LimitsRequest,
    MakeRequest, PerturbRequest, RenderRequest, ResetRequest, RunRequest, SessionRequest,
    StepRequest, TasksRequest, keys,
};
use ciflow_bridge::query_all;
use common::*;
use proptest::prelude::*;
use serde::ser::{SerializeMap, SerializeSeq};
use serde::{Serialize, Serializer};

/// Any MessagePack value.
#[derive(Clone, Debug)]
enum Value {
    Nil,
    Bool(bool),
    Int(i64),
    Float(f64),
    Text(String),
    Bin(Vec<u8>),
    Array(Vec<Value>),
    Map(Vec<(String, Value)>),
}

impl Serialize for Value {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Value::Nil => serializer.serialize_unit(),
            Value::Bool(b) => serializer.serialize_bool(*b),
            Value::Int(i) => serializer.serialize_i64(*i),
            Value::Float(f) => serializer.serialize_f64(*f),
            Value::Text(s) => serializer.serialize_str(s),
            Value::Bin(b) => serializer.serialize_bytes(b),
            Value::Array(items) => {
                let mut seq = serializer.serialize_seq(Some(items.len()))?;
                for item in items {
                    seq.serialize_element(item)?;
                }
                seq.end()
            }
            Value::Map(entries) => {
                let mut map = serializer.serialize_map(Some(entries.len()))?;
                for (key, value) in entries {
                    map.serialize_entry(key, value)?;
                }
                map.end()
            }
        }
    }
}

/// Every field name of the protocol's requests, so that generated maps reach past the
/// first missing field into the handlers.
const FIELDS: &[&str] = &[
    "v",
    "token",
    "action",
    "actions",
    "seed",
    "options",
    "context",
    "initial_position",
    "initial_velocity",
    "extra",
    "index",
    "perturbation",
    "kind",
    "torque",
    "force",
    "link",
    "start",
    "duration",
    "width",
    "height",
    "instance",
    "task",
    "num_envs",
    "kwargs",
    "observations",
    "policy",
    "speed",
    "steps",
    "deadline_ms",
];

fn float() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(-1e308),
        Just(0.0),
        -2.0..2.0f64,
        any::<f64>(),
    ]
}

fn value() -> impl Strategy<Value = Value> {
    let leaf = prop_oneof![
        Just(Value::Nil),
        any::<bool>().prop_map(Value::Bool),
        prop_oneof![
            Just(1i64),
            Just(0),
            Just(-1),
            Just(u32::MAX as i64),
            any::<i64>()
        ]
        .prop_map(Value::Int),
        float().prop_map(Value::Float),
        "[a-z_/*]{0,12}".prop_map(Value::Text),
        prop::collection::vec(any::<u8>(), 0..40).prop_map(Value::Bin),
        prop::collection::vec(float(), 0..6)
            .prop_map(|v| Value::Bin(v.iter().flat_map(|x| x.to_le_bytes()).collect())),
    ];
    leaf.prop_recursive(3, 24, 6, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..6).prop_map(Value::Array),
            prop::collection::vec((prop::sample::select(FIELDS), inner), 0..6).prop_map(
                |entries| Value::Map(
                    entries
                        .into_iter()
                        .map(|(k, v)| (k.to_owned(), v))
                        .collect()
                )
            ),
        ]
    })
}

/// A request-shaped map: mostly the protocol's version and the protocol's field names.
fn request() -> impl Strategy<Value = Value> {
    (
        prop_oneof![4 => Just(Value::Int(i64::from(ciflow_bridge::protocol::PROTOCOL_VERSION))), 1 => value()],
        prop::collection::vec((prop::sample::select(FIELDS), value()), 0..8),
    )
        .prop_map(|(v, entries)| {
            let mut map = vec![("v".to_owned(), v)];
            map.extend(entries.into_iter().map(|(k, v)| (k.to_owned(), v)));
            Value::Map(map)
        })
}

fn payload() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        3 => request().prop_map(|r| rmp_serde::to_vec(&r).unwrap()),
        1 => value().prop_map(|v| rmp_serde::to_vec(&v).unwrap()),
        1 => prop::collection::vec(any::<u8>(), 0..64),
    ]
}

/// A request-shaped map holding the session's real token, so that it passes the owner
/// check and reaches the operation's handler.
fn owned_request(token: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    request().prop_map(move |request| {
        let Value::Map(mut entries) = request else {
            unreachable!("requests are maps")
        };
        entries.retain(|(key, _)| key != "token");
        entries.insert(1, ("token".to_owned(), Value::Bin(token.clone())));
        rmp_serde::to_vec(&Value::Map(entries)).unwrap()
    })
}

/// Decoding may fail, but only with a decoding error, and never panics.
fn decodes_or_refuses<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<(), TestCaseError> {
    if let Err(error) = protocol::decode_request::<T>(bytes) {
        prop_assert!(
            matches!(
                error.code,
                ErrorCode::Malformed | ErrorCode::VersionMismatch | ErrorCode::PayloadTooLarge
            ),
            "decoding gave {}",
            error.code
        );
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn the_decoder_refuses_what_it_cannot_read_with_a_decoding_error(bytes in payload()) {
        decodes_or_refuses::<TasksRequest>(&bytes)?;
        decodes_or_refuses::<LimitsRequest>(&bytes)?;
        decodes_or_refuses::<MakeRequest>(&bytes)?;
        decodes_or_refuses::<ResetRequest>(&bytes)?;
        decodes_or_refuses::<StepRequest>(&bytes)?;
        decodes_or_refuses::<BatchStepRequest>(&bytes)?;
        decodes_or_refuses::<SessionRequest>(&bytes)?;
        decodes_or_refuses::<ContextRequest>(&bytes)?;
        decodes_or_refuses::<PerturbRequest>(&bytes)?;
        decodes_or_refuses::<RenderRequest>(&bytes)?;
        decodes_or_refuses::<RunRequest>(&bytes)?;
        decodes_or_refuses::<ActRequest>(&bytes)?;
        decodes_or_refuses::<CheckpointMsg>(&bytes)?;
    }
}

#[test]
fn every_operation_answers_anything_once_and_the_engine_keeps_serving() {
    let engine = start_engine(27441);
    let client = connect(27441);
    let steady = client
        .make(engine.name(), "fixture", 1, &BTreeMap::new())
        .unwrap();
    let make_target = || {
        client
            .make(engine.name(), "fixture", 2, &BTreeMap::new())
            .unwrap()
    };
    let engine_keys = [
        keys::tasks(engine.name()),
        keys::make(engine.name(), keys::ANONYMOUS),
        keys::limits(engine.name(), keys::ANONYMOUS),
        keys::policy_act(engine.name(), "none"),
    ];
    // The session under test; a generated `close` that succeeds gets a fresh one.
    let target = RefCell::new(make_target());
    let zs = client.zenoh_session().clone();
    let config = ProptestConfig {
        cases: 150,
        failure_persistence: None,
        ..ProptestConfig::default()
    };
    let codes = RefCell::new(BTreeMap::<String, usize>::new());
    // Engine-level keys (`None`) first, then every session operation.
    let engine_ops = engine_keys.iter().map(|key| (Some(key), None));
    let session_ops = keys::SessionOp::ALL.map(|op| (None, Some(op)));
    for (engine_key, op) in engine_ops.chain(session_ops) {
        let token = target.borrow().token().to_vec();
        // A runner counts cases over its lifetime: one per operation.
        proptest::test_runner::TestRunner::new(config.clone())
            .run(&prop_oneof![payload(), owned_request(token)], |bytes| {
                let key = match (engine_key, op) {
                    (Some(key), _) => key.clone(),
                    (None, Some(op)) => keys::session(
                        engine.name(),
                        keys::ANONYMOUS,
                        target.borrow().session_id(),
                        op.as_str(),
                    ),
                    (None, None) => unreachable!("every case names a key or an operation"),
                };
                let replies = query_all(&zs, &key, bytes, Duration::from_secs(10)).unwrap();
                prop_assert_eq!(replies.len(), 1, "exactly one reply on {}", key);
                let code = match &replies[0] {
                    Ok(_) => "ok".to_owned(),
                    Err(error) => {
                        prop_assert!(
                            error.code != ErrorCode::Internal,
                            "{}: {}",
                            key,
                            error.message
                        );
                        error.code.to_string()
                    }
                };
                if op == Some(keys::SessionOp::Close) && code == "ok" {
                    *target.borrow_mut() = make_target();
                }
                *codes.borrow_mut().entry(code).or_default() += 1;
                Ok(())
            })
            .unwrap_or_else(|failure| panic!("{engine_key:?} {op:?}: {failure}"));
    }
    let codes = codes.into_inner();
    println!("replies by code: {codes:?}");
    // The generated requests reach past decoding: some succeed, some fail in handlers.
    for code in ["ok", "malformed"] {
        assert!(codes.contains_key(code), "no `{code}` reply in {codes:?}");
    }
    let decoding = [
        "ok",
        "malformed",
        "version_mismatch",
        "payload_too_large",
        "unknown_session",
    ];
    assert!(
        codes
            .keys()
            .filter(|c| !decoding.contains(&c.as_str()))
            .count()
            >= 2,
        "too few requests reached the handlers: {codes:?}"
    );
    assert!(
        !codes.contains_key("unknown_session"),
        "the target was lost: {codes:?}"
    );
    steady.reset(Some(0), None).unwrap();
    steady.step(&[0.1]).expect("the engine still serves");
}
