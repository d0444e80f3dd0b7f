//! The wire format's fixed numbers, and the strict readers of fields whose serde default
//! would accept more than the protocol allows.

use std::collections::BTreeMap;
use std::fmt;

use ciflow_envs::ResetOptions;
use serde::de::{self, Visitor};
use serde::{Deserialize, Deserializer};
use serde_bytes::ByteBuf;

use super::F64s;

/// Bumped on every incompatible change; requests with another `v` get `version_mismatch`.
pub const PROTOCOL_VERSION: u16 = 2;

/// Largest request payload the engine decodes (64 MiB, e.g. a `step_batch` of 1M
/// two-dimensional actions is 16 MiB).
pub const MAX_REQUEST_BYTES: usize = 64 << 20;

/// Length of a session's secret token.
pub const TOKEN_BYTES: usize = 16;

/// Deserializes a MessagePack `bin` and nothing else (a session token): serde's byte
/// buffers would also take an array of integers, which the protocol does not allow.
pub(crate) fn bin_only<'de, D: Deserializer<'de>>(deserializer: D) -> Result<ByteBuf, D::Error> {
    struct Bin;
    impl Visitor<'_> for Bin {
        type Value = ByteBuf;

        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a MessagePack bin")
        }

        fn visit_bytes<E: de::Error>(self, bytes: &[u8]) -> Result<ByteBuf, E> {
            Ok(ByteBuf::from(bytes.to_vec()))
        }

        fn visit_byte_buf<E: de::Error>(self, bytes: Vec<u8>) -> Result<ByteBuf, E> {
            Ok(ByteBuf::from(bytes))
        }
    }
    deserializer.deserialize_bytes(Bin)
}

/// [`ResetOptions`] as they travel: their vectors are `f64s` like every other real vector
/// (a `bin` of little-endian doubles, or an array of numbers), never a `bin` read one
/// number per byte.
#[derive(Deserialize)]
struct ResetOptionsWire {
    #[serde(default)]
    context: Option<F64s>,
    #[serde(default)]
    initial_position: Option<F64s>,
    #[serde(default)]
    initial_velocity: Option<F64s>,
    #[serde(default)]
    extra: BTreeMap<String, f64>,
}

pub(crate) fn reset_options<'de, D: Deserializer<'de>>(
    deserializer: D,
) -> Result<Option<ResetOptions>, D::Error> {
    let wire = Option::<ResetOptionsWire>::deserialize(deserializer)?;
    Ok(wire.map(|wire| ResetOptions {
        context: wire.context.map(|v| v.0),
        initial_position: wire.initial_position.map(|v| v.0),
        initial_velocity: wire.initial_velocity.map(|v| v.0),
        extra: wire.extra,
    }))
}

/// Whether `payload` starts with a MessagePack map marker (fixmap, map 16, map 32):
/// every request is a map, and serde would otherwise read an array as a struct.
pub(crate) fn is_map(payload: &[u8]) -> bool {
    matches!(payload.first(), Some(0x80..=0x8f | 0xde | 0xdf))
}
