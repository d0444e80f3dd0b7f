//! One request, its replies: the query helpers every client of the protocol uses.

use std::time::Duration;

use serde::de::DeserializeOwned;
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::query::{ConsolidationMode, Reply};

use crate::error::BridgeError;
use crate::protocol::{ErrorReply, decode_reply};

/// Sends `payload` to `key`; every matching queryable's reply arrives on the handler
/// (none are merged), until `timeout`.
fn send(
    zsession: &zenoh::Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<FifoChannelHandler<Reply>, BridgeError> {
    zsession
        .get(key)
        .payload(payload)
        .consolidation(ConsolidationMode::None)
        .timeout(timeout)
        .wait()
        .map_err(BridgeError::zenoh("sending a query"))
}

/// Sends raw `payload` to `key` and collects every reply until the query completes: each
/// is the reply payload or the engine's typed error. For tools and tests that speak the
/// protocol by hand (the engine always sends exactly one).
pub fn query_all(
    zsession: &zenoh::Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<Vec<Result<Vec<u8>, ErrorReply>>, BridgeError> {
    let replies = send(zsession, key, payload, timeout)?;
    replies
        .iter()
        .map(
            |reply| match decode_ok::<serde::de::IgnoredAny>(key, &reply) {
                Ok(_) => Ok(Ok(reply
                    .result()
                    .map(|s| s.payload().to_bytes().into_owned())
                    .unwrap_or_default())),
                Err(BridgeError::Remote(error)) => Ok(Err(error)),
                Err(other) => Err(other),
            },
        )
        .collect()
}

/// One query, one reply.
pub(crate) fn query<R: DeserializeOwned>(
    zsession: &zenoh::Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<R, BridgeError> {
    let replies = send(zsession, key, payload, timeout)?;
    first_reply(key, &replies)
}

pub(crate) fn first_reply<R: DeserializeOwned>(
    key: &str,
    replies: &FifoChannelHandler<Reply>,
) -> Result<R, BridgeError> {
    match replies.recv() {
        Ok(reply) => decode_ok(key, &reply),
        Err(_) => Err(BridgeError::NoEngine {
            key: key.to_owned(),
        }),
    }
}

pub(crate) fn decode_ok<R: DeserializeOwned>(key: &str, reply: &Reply) -> Result<R, BridgeError> {
    match reply.result() {
        Ok(sample) => {
            decode_reply(&sample.payload().to_bytes()).map_err(|source| BridgeError::BadReply {
                key: key.to_owned(),
                source,
            })
        }
        Err(error) => {
            let bytes = error.payload().to_bytes();
            match decode_reply::<ErrorReply>(&bytes) {
                Ok(remote) => Err(BridgeError::Remote(remote)),
                Err(source) => Err(BridgeError::BadErrorReply {
                    key: key.to_owned(),
                    payload: String::from_utf8_lossy(&bytes).into_owned(),
                    source,
                }),
            }
        }
    }
}
