//! One request, its replies: the query helpers every client of the protocol uses.

use std::time::{Duration, Instant};

use serde::de::DeserializeOwned;
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::FifoChannelHandler;
use zenoh::query::{ConsolidationMode, Reply};

use crate::error::BridgeError;
use crate::protocol::{ErrorReply, decode_reply};
use crate::retry::retry_within;

/// Sends `payload` to `key`; every matching queryable's reply arrives on the handler
/// (none are merged), until `timeout`.
fn get(
    zsession: &zenoh::Session,
    key: &str,
    payload: impl Into<ZBytes>,
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
    let replies = get(zsession, key, payload, timeout)?;
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

/// One query, one reply (see [`retry_unrouted`]).
pub(crate) fn query<R: DeserializeOwned>(
    zsession: &zenoh::Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<R, BridgeError> {
    send_query(zsession, key, payload, timeout)?.reply()
}

/// Sends `payload` to `key` as [`query`] does, its reply left to take.
pub(crate) fn send_query<'a>(
    zsession: &'a zenoh::Session,
    key: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<Pending<'a>, BridgeError> {
    let get_key = key.to_owned();
    Pending::send(key.to_owned(), payload, timeout, move |payload| {
        get(zsession, &get_key, payload, timeout)
    })
}

/// How a [`Pending`] query goes out (again): a `get` on its key, or a declared querier's.
type SendQuery<'a> = Box<dyn Fn(ZBytes) -> Result<FifoChannelHandler<Reply>, BridgeError> + 'a>;

/// A query on its way to one engine, its reply not taken yet: queries to several engines
/// are sent first and their replies taken after, so the engines work at the same time.
pub(crate) struct Pending<'a> {
    key: String,
    /// Shared, not copied, between attempts.
    payload: ZBytes,
    timeout: Duration,
    send: SendQuery<'a>,
    sent: Instant,
    replies: FifoChannelHandler<Reply>,
}

impl<'a> Pending<'a> {
    /// Sends `payload` to `key` through `send`.
    pub(crate) fn send(
        key: String,
        payload: Vec<u8>,
        timeout: Duration,
        send: impl Fn(ZBytes) -> Result<FifoChannelHandler<Reply>, BridgeError> + 'a,
    ) -> Result<Self, BridgeError> {
        let payload = ZBytes::from(payload);
        let sent = Instant::now();
        let replies = send(payload.clone())?;
        Ok(Self {
            key,
            payload,
            timeout,
            send: Box::new(send),
            sent,
            replies,
        })
    }

    /// The query's one reply, the query sent again while it reached no engine
    /// ([`retry_unrouted`]).
    pub(crate) fn reply<R: DeserializeOwned>(self) -> Result<R, BridgeError> {
        self.reply_with(|payload| decode_reply(payload))
    }

    /// The query's one reply as `decode` reads its payload (in place, say), the query sent
    /// again as [`reply`](Self::reply) does.
    pub(crate) fn reply_with<R>(
        self,
        mut decode: impl FnMut(&[u8]) -> Result<R, rmp_serde::decode::Error>,
    ) -> Result<R, BridgeError> {
        let mut first = Some((self.replies, self.sent));
        retry_unrouted(self.timeout, || {
            let (replies, sent) = match first.take() {
                Some(first) => first,
                None => {
                    let sent = Instant::now();
                    ((self.send)(self.payload.clone())?, sent)
                }
            };
            first_reply(&self.key, &replies, sent, &mut decode)
        })
    }
}

/// How long a request that reached no engine is sent again before it fails as
/// [`BridgeError::NoEngine`], at most half the client's timeout ([`crate::retry`]: ~1 s
/// after a reconnection in eclipse-zenoh/zenoh#2767). The engine answers every request
/// it receives, so one that got no reply at all never reached it and is safe to repeat.
const UNROUTED_RETRY: Duration = Duration::from_secs(1);

/// `attempt`, repeated while it fails with [`BridgeError::NoEngine`] (see
/// [`retry_while_unrouted`]); any other outcome is returned at once.
fn retry_unrouted<R>(
    timeout: Duration,
    attempt: impl FnMut() -> Result<R, BridgeError>,
) -> Result<R, BridgeError> {
    retry_while_unrouted(timeout, attempt, |outcome| {
        matches!(outcome, Err(BridgeError::NoEngine { .. }))
    })
}

/// `attempt`, repeated while `unrouted` says it reached no engine, within
/// [`UNROUTED_RETRY`] (at most half of `timeout`).
fn retry_while_unrouted<R>(
    timeout: Duration,
    attempt: impl FnMut() -> Result<R, BridgeError>,
    unrouted: impl Fn(&Result<R, BridgeError>) -> bool,
) -> Result<R, BridgeError> {
    retry_within(UNROUTED_RETRY.min(timeout / 2), attempt, unrouted)
}

/// `attempt`, a query to every engine, repeated while it finds none (see
/// [`retry_while_unrouted`]): right after joining, e.g. as a Zenoh peer that a router
/// introduces to the engines, the routes are not settled yet and a query reaches nobody.
/// Answers from some of the engines are returned at once.
pub(crate) fn retry_unanswered<T>(
    timeout: Duration,
    attempt: impl FnMut() -> Result<Vec<T>, BridgeError>,
) -> Result<Vec<T>, BridgeError> {
    retry_while_unrouted(
        timeout,
        attempt,
        |outcome| matches!(outcome, Ok(answers) if answers.is_empty()),
    )
}

/// The first reply of a query sent at `sent`. Zenoh ends a query with no reply at all when
/// no queryable matches it, and with its own error reply `Timeout` when one matched but
/// did not answer in time (the engine's errors are always encoded [`ErrorReply`]s).
fn first_reply<R>(
    key: &str,
    replies: &FifoChannelHandler<Reply>,
    sent: Instant,
    decode: impl FnOnce(&[u8]) -> Result<R, rmp_serde::decode::Error>,
) -> Result<R, BridgeError> {
    match replies.recv() {
        Ok(reply) => decode_ok_with(key, &reply, sent, decode),
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
    decode_ok_with(key, reply, sent, |payload| decode_reply(payload))
}

/// [`decode_ok`] with the payload read by `decode`.
fn decode_ok_with<R>(
    key: &str,
    reply: &Reply,
    sent: Instant,
    decode: impl FnOnce(&[u8]) -> Result<R, rmp_serde::decode::Error>,
) -> Result<R, BridgeError> {
    if is_zenoh_timeout(reply) {
        return Err(BridgeError::NoReply {
            key: key.to_owned(),
            waited: sent.elapsed(),
        });
    }
    match reply.result() {
        Ok(sample) => {
            decode(&sample.payload().to_bytes()).map_err(|source| BridgeError::BadReply {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn no_engine() -> BridgeError {
        BridgeError::NoEngine {
            key: "ciflow/v2/engine/absent/ping".into(),
        }
    }

    #[test]
    fn a_request_that_reached_nobody_is_sent_again_within_the_window() {
        let mut attempts = 0;
        let outcome = retry_unrouted(Duration::from_secs(10), || {
            attempts += 1;
            if attempts < 3 {
                Err(no_engine())
            } else {
                Ok(attempts)
            }
        });
        assert_eq!(outcome.unwrap(), 3, "reached on the third attempt");
    }

    #[test]
    fn nobody_after_the_window_is_no_engine_and_other_errors_are_not_repeated() {
        let started = Instant::now();
        let mut attempts = 0;
        let outcome: Result<(), _> = retry_unrouted(Duration::from_millis(400), || {
            attempts += 1;
            Err(no_engine())
        });
        let waited = started.elapsed();
        assert!(matches!(outcome, Err(BridgeError::NoEngine { .. })));
        // Half the timeout bounds the window: 10 + 20 + 40 + 80 ms of pauses fit in it.
        assert!(attempts >= 4, "{attempts} attempts");
        assert!(
            waited < Duration::from_millis(400),
            "gave up after {waited:?}"
        );

        let mut attempts = 0;
        let outcome: Result<(), _> = retry_unrouted(Duration::from_secs(10), || {
            attempts += 1;
            Err(BridgeError::NoReply {
                key: "k".into(),
                waited: Duration::from_secs(10),
            })
        });
        assert!(matches!(outcome, Err(BridgeError::NoReply { .. })));
        assert_eq!(
            attempts, 1,
            "an engine that took the request is not asked twice"
        );
    }
}
