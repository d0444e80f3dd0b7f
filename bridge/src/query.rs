//! One request, its replies: the query helpers every client of the protocol uses.

use std::time::{Duration, Instant};

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
    let sent = Instant::now();
    let replies = send(zsession, key, payload, timeout)?;
    replies
        .iter()
        .map(
            |reply| match decode_ok::<serde::de::IgnoredAny>(key, &reply, sent) {
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
    let sent = Instant::now();
    let replies = send(zsession, key, payload, timeout)?;
    first_reply(key, &replies, sent)
}

/// The first reply of a query sent at `sent`. Zenoh ends a query with no reply at all when
/// no queryable matches it, and with its own error reply `Timeout` when one matched but
/// did not answer in time (the engine's errors are always encoded [`ErrorReply`]s).
pub(crate) fn first_reply<R: DeserializeOwned>(
    key: &str,
    replies: &FifoChannelHandler<Reply>,
    sent: Instant,
) -> Result<R, BridgeError> {
    match replies.recv() {
        Ok(reply) => decode_ok(key, &reply, sent),
        Err(_) => Err(BridgeError::NoEngine {
            key: key.to_owned(),
        }),
    }
}

/// Whether `reply` is the error Zenoh itself delivers when a query times out.
fn is_zenoh_timeout(reply: &Reply) -> bool {
    reply
        .result()
        .is_err_and(|error| *error.payload().to_bytes() == *b"Timeout")
}

/// The payload of `reply` to a query sent at `sent`, or its error: the engine's typed
/// [`ErrorReply`], or Zenoh's own timeout.
pub(crate) fn decode_ok<R: DeserializeOwned>(
    key: &str,
    reply: &Reply,
    sent: Instant,
) -> Result<R, BridgeError> {
    if is_zenoh_timeout(reply) {
        return Err(BridgeError::NoReply {
            key: key.to_owned(),
            waited: sent.elapsed(),
        });
    }
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
