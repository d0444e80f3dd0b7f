//! Key expressions of protocol version 2. See `PROTOCOL.md` for the full table.
//!
//! ```text
//! ciflow/v2/alive/engine/<engine>                    liveliness token of an engine
//! ciflow/v2/alive/client/<identity>/<instance>       liveliness token of a client process
//! ciflow/v2/engine/<engine>/tasks                    query: tasks, specs, policies
//! ciflow/v2/engine/<engine>/ping                     query: echoes its payload
//! ciflow/v2/engine/<engine>/policy/<policy>/act      query: observation in, action out
//! ciflow/v2/engine/<engine>/client/<identity>/make   query: open a session
//! ciflow/v2/engine/<engine>/client/<identity>/limits query: the engine's bounds, a
//!                                                    client's usage
//! …/client/<identity>/session/<session>/<op>         query: reset, step, reset_batch,
//!                                                    step_batch, expert, context,
//!                                                    check_context, perturb, render,
//!                                                    close, run, stop
//! …/client/<identity>/session/<session>/telemetry    publication (engine → viewers)
//! …/client/<identity>/session/<session>/frame        publication (rendered frames)
//! ciflow/v2/policies/<policy>/checkpoint             publication (trainer → engines)
//! ciflow/v2/episodes/<task>/<recorder>               publication: finished episodes
//! ```
//!
//! `<identity>` says who a client is; everything it owns lives under its
//! `…/client/<identity>/` prefix, so a Zenoh router's access control, which sees keys and
//! authenticated identities but not payloads, can confine each identity to its own
//! sessions (see `deploy/secure/`). Without access control every process is
//! [`ANONYMOUS`] unless it says otherwise. `<instance>` tells the processes of one
//! identity apart: each owns its sessions, closed when its token goes away.

/// Root of every key of this protocol version.
pub const ROOT: &str = "ciflow/v2";

/// Liveliness key of an engine.
pub fn engine_alive(engine: &str) -> String {
    format!("{ROOT}/alive/engine/{engine}")
}

/// Liveliness keys of all engines (for discovery).
pub const ALL_ENGINES_ALIVE: &str = "ciflow/v2/alive/engine/*";

/// The identity of a process that does not say who it is.
pub const ANONYMOUS: &str = "anonymous";

/// The name of one client process, `<identity>/<instance>`: what owns sessions.
pub fn client(identity: &str, instance: &str) -> String {
    format!("{identity}/{instance}")
}

/// Liveliness key of a client process; `client` is `<identity>/<instance>`.
pub fn client_alive(client: &str) -> String {
    format!("{ROOT}/alive/client/{client}")
}

/// Liveliness keys of all client processes (the engine watches them to reclaim sessions).
pub const ALL_CLIENTS_ALIVE: &str = "ciflow/v2/alive/client/*/*";

/// The `<identity>/<instance>` of a client's liveliness key.
pub fn parse_client_alive(key: &str) -> Option<&str> {
    let client = key.strip_prefix(ROOT)?.strip_prefix("/alive/client/")?;
    let (identity, instance) = client.split_once('/')?;
    (is_plain_chunk(identity) && is_plain_chunk(instance)).then_some(client)
}

/// Prefix of everything an engine serves.
pub fn engine(engine: &str) -> String {
    format!("{ROOT}/engine/{engine}")
}

/// The `tasks` query of every engine at once (for discovery).
pub const ALL_ENGINES_TASKS: &str = "ciflow/v2/engine/*/tasks";

pub fn tasks(engine_id: &str) -> String {
    format!("{}/tasks", engine(engine_id))
}

/// Prefix of everything `identity` owns on an engine.
pub fn client_prefix(engine_id: &str, identity: &str) -> String {
    format!("{}/client/{identity}", engine(engine_id))
}

pub fn make(engine_id: &str, identity: &str) -> String {
    format!("{}/make", client_prefix(engine_id, identity))
}

/// Echo: the raw Zenoh round trip to an engine, without the protocol's decoding.
pub fn ping(engine_id: &str) -> String {
    format!("{}/ping", engine(engine_id))
}

/// The engine's bounds and one client's usage of them.
pub fn limits(engine_id: &str, identity: &str) -> String {
    format!("{}/limits", client_prefix(engine_id, identity))
}

/// A per-session key of a session `identity` owns: an operation, `telemetry` or `frame`.
pub fn session(engine_id: &str, identity: &str, session: &str, leaf: &str) -> String {
    format!(
        "{}/session/{session}/{leaf}",
        client_prefix(engine_id, identity)
    )
}

pub fn policy_act(engine_id: &str, policy: &str) -> String {
    format!("{}/policy/{policy}/act", engine(engine_id))
}

pub fn policy_evaluate(engine_id: &str, policy: &str) -> String {
    format!("{}/policy/{policy}/evaluate", engine(engine_id))
}

pub fn policy_stability(engine_id: &str, policy: &str) -> String {
    format!("{}/policy/{policy}/stability", engine(engine_id))
}

// ---------------------------------------------------------------- policy publications

/// Where a trainer publishes checkpoints of policy `<policy>` (pub/sub: about 1 MB).
pub fn policy_checkpoint(policy: &str) -> String {
    format!("{ROOT}/policies/{policy}/checkpoint")
}

/// Every policy's checkpoint publications (engines subscribe to hot-load).
pub const ALL_POLICY_CHECKPOINTS: &str = "ciflow/v2/policies/*/checkpoint";

/// Whether `chunk` can be one chunk of a key expression: non-empty, no `/`, no wildcard
/// or reserved character. Engine, client, session and policy names must satisfy it.
pub fn is_plain_chunk(chunk: &str) -> bool {
    !chunk.is_empty()
        && chunk
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.'))
}

/// What a query addressed to one engine asks for, parsed from the key after
/// `ciflow/v2/engine/<engine>/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Route<'a> {
    Tasks,
    Ping,
    PolicyAct {
        policy: &'a str,
    },
    PolicyEvaluate {
        policy: &'a str,
    },
    PolicyStability {
        policy: &'a str,
    },
    Make {
        identity: &'a str,
    },
    Limits {
        identity: &'a str,
    },
    Session {
        identity: &'a str,
        session: &'a str,
        op: SessionOp,
    },
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
    /// The session's task and construction arguments, for viewers (no token).
    Describe,
}

impl SessionOp {
    pub const ALL: [SessionOp; 13] = [
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
        SessionOp::Describe,
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
            SessionOp::Describe => "describe",
        }
    }

    fn parse(op: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|o| o.as_str() == op)
    }
}

/// Parses the full key of a query received by the queryable on
/// `ciflow/v2/engine/<engine>/**`. `None` for keys outside the protocol (including
/// wildcard chunks where a name is expected).
pub fn parse_route(key: &str) -> Option<Route<'_>> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/engine/")?;
    let (_engine, rest) = rest.split_once('/')?;
    let chunks: Vec<&str> = rest.split('/').collect();
    match chunks.as_slice() {
        ["tasks"] => Some(Route::Tasks),
        ["ping"] => Some(Route::Ping),
        ["policy", policy, "act"] if is_plain_chunk(policy) => Some(Route::PolicyAct { policy }),
        ["policy", policy, "evaluate"] if is_plain_chunk(policy) => {
            Some(Route::PolicyEvaluate { policy })
        }
        ["policy", policy, "stability"] if is_plain_chunk(policy) => {
            Some(Route::PolicyStability { policy })
        }
        ["client", identity, owned @ ..] if is_plain_chunk(identity) => match owned {
            ["make"] => Some(Route::Make { identity }),
            ["limits"] => Some(Route::Limits { identity }),
            ["session", session, op] if is_plain_chunk(session) => Some(Route::Session {
                identity,
                session,
                op: SessionOp::parse(op)?,
            }),
            _ => None,
        },
        _ => None,
    }
}

/// The engine, owner identity and session of a telemetry key
/// (`ciflow/v2/engine/<engine>/client/<identity>/session/<session>/telemetry`).
pub fn parse_telemetry(key: &str) -> Option<(&str, &str, &str)> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/engine/")?;
    let chunks: Vec<&str> = rest.split('/').collect();
    match chunks.as_slice() {
        [engine, "client", identity, "session", session, "telemetry"]
            if [engine, identity, session]
                .iter()
                .all(|c| is_plain_chunk(c)) =>
        {
            Some((engine, identity, session))
        }
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

/// The policy of a checkpoint key; `None` outside `ciflow/v2/policies/<policy>/checkpoint`.
/// The name is returned as published: whether it is a valid policy name is the loader's
/// to say.
pub fn parse_policy_checkpoint(key: &str) -> Option<&str> {
    key.strip_prefix(ROOT)?
        .strip_prefix("/policies/")?
        .strip_suffix("/checkpoint")
}

/// `(task, recorder)` of an episode key; `None` outside `ciflow/v2/episodes/<task>/<recorder>`.
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
        assert_eq!(parse_policy_checkpoint("ciflow/v2/policies/p/act"), None);
    }

    #[test]
    fn every_built_key_parses_back_to_its_route() {
        assert_eq!(parse_route(&tasks("e1")), Some(Route::Tasks));
        assert_eq!(parse_route(ALL_ENGINES_TASKS), Some(Route::Tasks));
        assert_eq!(
            parse_route(&make("e1", "alice")),
            Some(Route::Make { identity: "alice" })
        );
        assert_eq!(parse_route(&ping("e1")), Some(Route::Ping));
        assert_eq!(
            parse_route(&limits("e1", "alice")),
            Some(Route::Limits { identity: "alice" })
        );
        for op in SessionOp::ALL {
            assert_eq!(
                parse_route(&session("e1", "alice", "s42", op.as_str())),
                Some(Route::Session {
                    identity: "alice",
                    session: "s42",
                    op
                })
            );
        }
        assert_eq!(
            parse_route(&policy_act("e1", "pour")),
            Some(Route::PolicyAct { policy: "pour" })
        );
        assert_eq!(
            parse_route(&policy_evaluate("e1", "pour")),
            Some(Route::PolicyEvaluate { policy: "pour" })
        );
        assert_eq!(
            parse_route(&policy_stability("e1", "pour")),
            Some(Route::PolicyStability { policy: "pour" })
        );
    }

    #[test]
    fn foreign_and_wildcard_keys_are_rejected() {
        for key in [
            "ciflow/v2/engine/e1",
            "ciflow/v2/engine/e1/make",
            "ciflow/v2/engine/e1/session/s1/step",
            "ciflow/v2/engine/e1/client/*/make",
            "ciflow/v2/engine/e1/client/a/session/*/step",
            "ciflow/v2/engine/e1/client/a/session/s1/fly",
            "ciflow/v2/engine/e1/client/a/session/s1/step/more",
            "ciflow/v2/engine/e1/client/a/tasks",
            "ciflow/v1/engine/e1/tasks",
            "other/engine/e1/tasks",
        ] {
            assert_eq!(parse_route(key), None, "{key}");
        }
    }

    #[test]
    fn telemetry_keys_name_their_engine_owner_and_session() {
        let key = session("e1", "alice", "s1", "telemetry");
        assert_eq!(parse_telemetry(&key), Some(("e1", "alice", "s1")));
        for key in [
            session("e1", "alice", "s1", "step"),
            session("e1", "*", "*", "telemetry"),
            session("e1", "alice", "s1", "frame"),
            "ciflow/v2/engine/e1/client/alice/session/s1/telemetry/extra".to_owned(),
        ] {
            assert_eq!(parse_telemetry(&key), None, "{key}");
        }
    }

    #[test]
    fn client_tokens_name_an_identity_and_an_instance() {
        let client = client("alice", "c1");
        assert_eq!(parse_client_alive(&client_alive(&client)), Some("alice/c1"));
        for key in [
            "ciflow/v2/alive/client/alice",
            "ciflow/v2/alive/client/alice/*",
            "ciflow/v2/alive/client/alice/c1/x",
            "ciflow/v2/alive/engine/e1",
        ] {
            assert_eq!(parse_client_alive(key), None, "{key}");
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
            "ciflow/v2/episodes/limit-cycle/*"
        );
        for key in [
            all_episodes("pouring").as_str(),
            "ciflow/v2/episodes/pouring",
            "ciflow/v2/episodes/pouring/rec/extra",
            "ciflow/v2/engine/e1/tasks",
        ] {
            assert_eq!(parse_episodes(key), None, "{key}");
        }
    }
}
