//! Key expressions of protocol version 1. See `PROTOCOL.md` for the full table.
//!
//! ```text
//! ciflow/v1/alive/engine/<engine>                    liveliness token of an engine
//! ciflow/v1/alive/client/<client>                    liveliness token of a client
//! ciflow/v1/engine/<engine>/tasks                    query: tasks, specs, policies
//! ciflow/v1/engine/<engine>/make                     query: open a session
//! ciflow/v1/engine/<engine>/ping                     query: echoes its payload
//! ciflow/v1/engine/<engine>/limits                   query: the engine's bounds, a
//!                                                    client's usage
//! ciflow/v1/engine/<engine>/session/<session>/<op>   query: reset, step, reset_batch,
//!                                                    step_batch, expert, context,
//!                                                    check_context, perturb, render,
//!                                                    close, run, stop
//! ciflow/v1/engine/<engine>/session/<session>/telemetry   publication (engine → viewers)
//! ciflow/v1/engine/<engine>/session/<session>/frame       publication (rendered frames)
//! ciflow/v1/engine/<engine>/policy/<policy>/act      query: observation in, action out
//! ciflow/v1/policies/<policy>/checkpoint             publication (trainer → engines)
//! ciflow/v1/episodes/<task>/<recorder>               publication: finished episodes
//! ```

/// Root of every key of this protocol version.
pub const ROOT: &str = "ciflow/v1";

/// Liveliness key of an engine.
pub fn engine_alive(engine: &str) -> String {
    format!("{ROOT}/alive/engine/{engine}")
}

/// Liveliness keys of all engines (for discovery).
pub const ALL_ENGINES_ALIVE: &str = "ciflow/v1/alive/engine/*";

/// Liveliness key of a client.
pub fn client_alive(client: &str) -> String {
    format!("{ROOT}/alive/client/{client}")
}

/// Liveliness keys of all clients (the engine watches them to reclaim sessions).
pub const ALL_CLIENTS_ALIVE: &str = "ciflow/v1/alive/client/*";

/// Prefix of everything an engine serves.
pub fn engine(engine: &str) -> String {
    format!("{ROOT}/engine/{engine}")
}

/// The `tasks` query of every engine at once (for discovery).
pub const ALL_ENGINES_TASKS: &str = "ciflow/v1/engine/*/tasks";

pub fn tasks(engine_id: &str) -> String {
    format!("{}/tasks", engine(engine_id))
}

pub fn make(engine_id: &str) -> String {
    format!("{}/make", engine(engine_id))
}

/// Echo: the raw Zenoh round trip to an engine, without the protocol's decoding.
pub fn ping(engine_id: &str) -> String {
    format!("{}/ping", engine(engine_id))
}

/// The engine's bounds and one client's usage of them.
pub fn limits(engine_id: &str) -> String {
    format!("{}/limits", engine(engine_id))
}

/// A per-session key: an operation, `telemetry` or `frame`.
pub fn session(engine_id: &str, session: &str, leaf: &str) -> String {
    format!("{}/session/{session}/{leaf}", engine(engine_id))
}

pub fn policy_act(engine_id: &str, policy: &str) -> String {
    format!("{}/policy/{policy}/act", engine(engine_id))
}

// ---------------------------------------------------------------- policy publications

/// Where a trainer publishes checkpoints of policy `<policy>` (pub/sub: about 1 MB).
pub fn policy_checkpoint(policy: &str) -> String {
    format!("{ROOT}/policies/{policy}/checkpoint")
}

/// Every policy's checkpoint publications (engines subscribe to hot-load).
pub const ALL_POLICY_CHECKPOINTS: &str = "ciflow/v1/policies/*/checkpoint";

/// Whether `chunk` can be one chunk of a key expression: non-empty, no `/`, no wildcard
/// or reserved character. Engine, client, session and policy names must satisfy it.
pub fn is_plain_chunk(chunk: &str) -> bool {
    !chunk.is_empty()
        && chunk
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
}

/// What a query addressed to one engine asks for, parsed from the key after
/// `ciflow/v1/engine/<engine>/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Route<'a> {
    Tasks,
    Make,
    Ping,
    Limits,
    Session { session: &'a str, op: SessionOp },
    PolicyAct { policy: &'a str },
}

/// Operations on one session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SessionOp {
    Reset,
    Step,
    ResetBatch,
    StepBatch,
    Expert,
    Context,
    /// Whether the task accepts a context, without changing anything.
    CheckContext,
    Perturb,
    Render,
    Close,
    /// Policy-driven sessions: the engine steps the environment itself.
    Run,
    Stop,
}

impl SessionOp {
    pub const ALL: [SessionOp; 12] = [
        SessionOp::Reset,
        SessionOp::Step,
        SessionOp::ResetBatch,
        SessionOp::StepBatch,
        SessionOp::Expert,
        SessionOp::Context,
        SessionOp::CheckContext,
        SessionOp::Perturb,
        SessionOp::Render,
        SessionOp::Close,
        SessionOp::Run,
        SessionOp::Stop,
    ];

    /// The last chunk of the operation's key.
    pub fn as_str(self) -> &'static str {
        match self {
            SessionOp::Reset => "reset",
            SessionOp::Step => "step",
            SessionOp::ResetBatch => "reset_batch",
            SessionOp::StepBatch => "step_batch",
            SessionOp::Expert => "expert",
            SessionOp::Context => "context",
            SessionOp::CheckContext => "check_context",
            SessionOp::Perturb => "perturb",
            SessionOp::Render => "render",
            SessionOp::Close => "close",
            SessionOp::Run => "run",
            SessionOp::Stop => "stop",
        }
    }

    fn parse(op: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.as_str() == op)
    }
}

/// Parses the full key of a query received by the queryable on
/// `ciflow/v1/engine/<engine>/**`. `None` for keys outside the protocol (including
/// wildcard chunks where a name is expected).
pub fn parse_route(key: &str) -> Option<Route<'_>> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/engine/")?;
    let (_engine, rest) = rest.split_once('/')?;
    let chunks: Vec<&str> = rest.split('/').collect();
    match chunks.as_slice() {
        ["tasks"] => Some(Route::Tasks),
        ["make"] => Some(Route::Make),
        ["ping"] => Some(Route::Ping),
        ["limits"] => Some(Route::Limits),
        ["session", session, op] if is_plain_chunk(session) => Some(Route::Session {
            session,
            op: SessionOp::parse(op)?,
        }),
        ["policy", policy, "act"] if is_plain_chunk(policy) => Some(Route::PolicyAct { policy }),
        _ => None,
    }
}

/// Where `recorder` publishes the finished episodes of `task` (its command-line name,
/// e.g. `pouring`; a Gymnasium id holds a `/`, so it cannot be one chunk).
pub fn episodes(task: &str, recorder: &str) -> String {
    format!("{ROOT}/episodes/{task}/{recorder}")
}

/// The episodes of `task` from every recorder (what a trainer subscribes to).
pub fn all_episodes(task: &str) -> String {
    episodes(task, "*")
}

/// The policy of a checkpoint key; `None` outside `ciflow/v1/policies/<policy>/checkpoint`.
/// The name is returned as published: whether it is a valid policy name is the loader's
/// to say.
pub fn parse_policy_checkpoint(key: &str) -> Option<&str> {
    key.strip_prefix(ROOT)?
        .strip_prefix("/policies/")?
        .strip_suffix("/checkpoint")
}

/// `(task, recorder)` of an episode key; `None` outside `ciflow/v1/episodes/<task>/<recorder>`.
pub fn parse_episodes(key: &str) -> Option<(&str, &str)> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/episodes/")?;
    match rest.split_once('/')? {
        (task, recorder) if is_plain_chunk(task) && is_plain_chunk(recorder) => {
            Some((task, recorder))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checkpoint_keys_name_their_policy() {
        assert_eq!(
            parse_policy_checkpoint(&policy_checkpoint("p-1")),
            Some("p-1")
        );
        assert_eq!(parse_policy_checkpoint("ciflow/v1/policies/p/act"), None);
    }

    #[test]
    fn every_built_key_parses_back_to_its_route() {
        assert_eq!(parse_route(&tasks("e1")), Some(Route::Tasks));
        assert_eq!(parse_route(ALL_ENGINES_TASKS), Some(Route::Tasks));
        assert_eq!(parse_route(&make("e1")), Some(Route::Make));
        assert_eq!(parse_route(&ping("e1")), Some(Route::Ping));
        assert_eq!(parse_route(&limits("e1")), Some(Route::Limits));
        for op in SessionOp::ALL {
            assert_eq!(
                parse_route(&session("e1", "s42", op.as_str())),
                Some(Route::Session { session: "s42", op })
            );
        }
        assert_eq!(
            parse_route(&policy_act("e1", "pour")),
            Some(Route::PolicyAct { policy: "pour" })
        );
    }

    #[test]
    fn foreign_and_wildcard_keys_are_rejected() {
        for key in [
            "ciflow/v1/engine/e1",
            "ciflow/v1/engine/e1/session/*/step",
            "ciflow/v1/engine/e1/session/s1/fly",
            "ciflow/v1/engine/e1/session/s1/step/more",
            "ciflow/v2/engine/e1/tasks",
            "other/engine/e1/tasks",
        ] {
            assert_eq!(parse_route(key), None, "{key}");
        }
    }

    #[test]
    fn plain_chunks_exclude_key_syntax() {
        assert!(is_plain_chunk("client-1.a_b"));
        for bad in ["", "a/b", "*", "**", "a$b", "a?b", "a#b"] {
            assert!(!is_plain_chunk(bad), "{bad}");
        }
    }

    #[test]
    fn episode_keys_parse_back() {
        assert_eq!(
            parse_episodes(&episodes("pouring", "rec-1")),
            Some(("pouring", "rec-1"))
        );
        assert_eq!(
            all_episodes("limit-cycle"),
            "ciflow/v1/episodes/limit-cycle/*"
        );
        for key in [
            all_episodes("pouring").as_str(),
            "ciflow/v1/episodes/pouring",
            "ciflow/v1/episodes/pouring/rec/extra",
            "ciflow/v1/engine/e1/tasks",
        ] {
            assert_eq!(parse_episodes(key), None, "{key}");
        }
    }
}
