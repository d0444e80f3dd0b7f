//! The wire protocol, version [`PROTOCOL_VERSION`]: key expressions ([`keys`]), MessagePack
//! payloads ([`messages`]), published demonstration episodes ([`episodes`]) and the typed
//! error reply ([`ErrorReply`]). `PROTOCOL.md` is the
//! language-neutral description of the same thing.

pub mod batch_step;
pub mod checkpoint;
pub mod episodes;
pub mod error;
pub mod f64le;
pub mod keys;
pub mod messages;
pub mod wire;

pub use batch_step::{
    BatchStepRows, BatchStepWriter, InfoBlock, MessageBuffer, context_update_len,
    context_update_max_len,
};
pub use checkpoint::{CheckpointMsg, CheckpointSignature, RunRequest};
pub use episodes::{EpisodeError, EpisodeMsg, decode_episode};
pub use error::{ErrorCode, ErrorReply};
pub use f64le::{F64Bin, F64Slice, F64s, write_le_bytes};
pub use messages::*;
pub use serde_bytes::ByteBuf;
pub use wire::{MAX_REQUEST_BYTES, PROTOCOL_VERSION, TOKEN_BYTES};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Encodes a message as a MessagePack map with named fields.
pub fn encode<T: Serialize>(message: &T) -> Vec<u8> {
    let mut buffer = Vec::new();
    rmp_serde::encode::write_named(&mut buffer, message)
        .expect("protocol messages always serialize");
    buffer
}

/// Decodes a request, telling a bad version from a malformed or oversized payload.
pub fn decode_request<T: DeserializeOwned>(payload: &[u8]) -> Result<T, ErrorReply> {
    if payload.len() > MAX_REQUEST_BYTES {
        return Err(ErrorReply::new(
            ErrorCode::PayloadTooLarge,
            format!(
                "request of {} bytes exceeds the limit of {MAX_REQUEST_BYTES} bytes",
                payload.len()
            ),
        ));
    }
    let version_error = |v: u16| {
        ErrorReply::new(
            ErrorCode::VersionMismatch,
            format!("request has protocol version {v}, this engine speaks {PROTOCOL_VERSION}"),
        )
    };
    if !wire::is_map(payload) {
        return Err(ErrorReply::new(
            ErrorCode::Malformed,
            "payload is not a MessagePack map",
        ));
    }
    match rmp_serde::from_slice::<Header>(payload) {
        Ok(Header { v, .. }) if v != PROTOCOL_VERSION => return Err(version_error(v)),
        Ok(_) => {}
        Err(e) => {
            return Err(ErrorReply::new(
                ErrorCode::Malformed,
                format!("payload is not a MessagePack map with a `v` field: {e}"),
            ));
        }
    }
    rmp_serde::from_slice(payload).map_err(|e| {
        ErrorReply::new(
            ErrorCode::Malformed,
            format!(
                "payload does not match the `{}` layout: {e}",
                std::any::type_name::<T>()
                    .rsplit("::")
                    .next()
                    .unwrap_or("request")
            ),
        )
    })
}

/// The caller's `deadline_ms`, if the payload is a request that carries one.
pub fn requested_deadline(payload: &[u8]) -> Option<u32> {
    if !wire::is_map(payload) {
        return None;
    }
    rmp_serde::from_slice::<Header>(payload).ok()?.deadline_ms
}

/// Decodes a reply payload (client side).
pub fn decode_reply<'a, T: Deserialize<'a>>(
    payload: &'a [u8],
) -> Result<T, rmp_serde::decode::Error> {
    rmp_serde::from_slice(payload)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_bytes::ByteBuf;

    #[test]
    fn decode_classifies_bad_payloads() {
        let step = StepRequest {
            v: PROTOCOL_VERSION,
            token: ByteBuf::from(vec![7; TOKEN_BYTES]),
            action: F64s(vec![0.5, -0.5]),
        };
        let good = encode(&step);
        assert_eq!(decode_request::<StepRequest>(&good).unwrap(), step);

        let code = |payload: &[u8]| decode_request::<StepRequest>(payload).unwrap_err().code;
        assert_eq!(code(b"\xff\x00garbage"), ErrorCode::Malformed);
        assert_eq!(code(&[]), ErrorCode::Malformed);
        assert_eq!(
            code(&encode(&TasksRequest {
                v: PROTOCOL_VERSION
            })),
            ErrorCode::Malformed
        );
        assert_eq!(
            code(&encode(&TasksRequest { v: 99 })),
            ErrorCode::VersionMismatch
        );
        assert_eq!(
            code(&vec![0u8; MAX_REQUEST_BYTES + 1]),
            ErrorCode::PayloadTooLarge
        );
    }

    #[test]
    fn perturbation_layout_is_flat_and_tagged() {
        let msg = PerturbationMsg {
            kind: PerturbationKindMsg::LinkWrench {
                link: 6,
                force: [1.0, 0.0, 0.0],
                torque: [0.0; 3],
            },
            start: None,
            duration: 0.2,
        };
        let bytes = encode(&msg);
        let value: rmpv_like::Map = rmp_serde::from_slice(&bytes).unwrap();
        assert_eq!(value.get("kind").map(String::as_str), Some("link_wrench"));
        assert_eq!(
            rmp_serde::from_slice::<PerturbationMsg>(&bytes).unwrap(),
            msg
        );
    }

    /// A string-only view of a map, enough to check key names without another crate.
    mod rmpv_like {
        use std::collections::BTreeMap;

        use serde::Deserialize;

        #[derive(Deserialize)]
        #[serde(transparent)]
        pub struct Map(BTreeMap<String, Loose>);

        impl Map {
            pub fn get(&self, key: &str) -> Option<&String> {
                match self.0.get(key)? {
                    Loose::Text(s) => Some(s),
                    Loose::Other(_) => None,
                }
            }
        }

        #[derive(Deserialize)]
        #[serde(untagged)]
        pub enum Loose {
            Text(String),
            Other(serde::de::IgnoredAny),
        }
    }
}
