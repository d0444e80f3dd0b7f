//! Hot-loading: a checkpoint published on `ciflow/v2/policies/<policy>/checkpoint`
//! replaces the policy served under that name, if it fits a task this engine serves,
//! keeps the policy's task and its observation and action shapes and, on an engine that
//! trusts keys, is signed by one of them. A policy served on its own data
//! (`--own-data-policy`) is replaced by the next checkpoint trained on that data, served
//! the same way.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::policy_table::PolicyTable;
use crate::checkpoint_policy::{CheckpointPolicy, PolicyLoadError};
use crate::policy::Policy;
use crate::protocol::keys;
use crate::protocol::{CheckpointMsg, ErrorReply, PolicyInfo, decode_request};
use crate::signing::{SignatureRefused, TrustedKeys};
use crate::task_factory::TaskFactory;
use ciflow_envs::actor::OWN_DATA_TASK;

/// How often one kind of refusal on one key is reported at most.
pub const REPORT_INTERVAL: Duration = Duration::from_secs(60);

/// Why a publication was not served.
#[derive(Debug, thiserror::Error)]
pub enum HotLoadError {
    #[error("`{0}` is not a checkpoint key")]
    NotCheckpointKey(String),
    #[error("undecodable publication")]
    Decode(#[source] ErrorReply),
    #[error("refused")]
    Signature(#[source] SignatureRefused),
    #[error(transparent)]
    Load(#[from] PolicyLoadError),
    #[error("policy `{name}` acts in {serving}, the checkpoint in {published}")]
    TaskChanged {
        name: String,
        serving: String,
        published: String,
    },
    #[error(
        "policy `{name}` acts on {} observations with {} actions, the checkpoint on {} with {}",
        serving.0, serving.1, published.0, published.1
    )]
    ShapeChanged {
        name: String,
        /// Observation and action dimensions.
        serving: (u32, u32),
        published: (u32, u32),
    },
}

impl HotLoadError {
    /// The kind of refusal, for rate-limited reporting.
    pub fn kind(&self) -> &'static str {
        match self {
            HotLoadError::NotCheckpointKey(_) => "key",
            HotLoadError::Decode(_) => "decode",
            HotLoadError::Signature(_) => "signature",
            HotLoadError::Load(_) => "load",
            HotLoadError::TaskChanged { .. } => "task",
            HotLoadError::ShapeChanged { .. } => "shape",
        }
    }
}

/// Swaps the checkpoint published on `key` into `policies`; returns what is now served.
/// With `trusted` keys, only a checkpoint one of them signed is considered.
pub fn hot_load(
    policies: &PolicyTable,
    factories: &[TaskFactory],
    trusted: Option<&TrustedKeys>,
    key: &str,
    payload: &[u8],
) -> Result<PolicyInfo, HotLoadError> {
    let name = keys::parse_policy_checkpoint(key)
        .ok_or_else(|| HotLoadError::NotCheckpointKey(key.to_owned()))?;
    let message: CheckpointMsg = decode_request(payload).map_err(HotLoadError::Decode)?;
    if let Some(trusted) = trusted {
        trusted.verify(&message).map_err(HotLoadError::Signature)?;
    }
    let current = policies.get(name);
    let serving = current.as_ref().map(|p| p.info());
    let on_own_data = serving.as_ref().is_some_and(|s| s.task == OWN_DATA_TASK);
    let policy = if on_own_data {
        CheckpointPolicy::from_message_on_own_data(name, &message, factories)?
    } else {
        let kwargs = current.map(|p| p.task_kwargs()).unwrap_or_default();
        CheckpointPolicy::from_message(name, &message, factories, &kwargs)?
    };
    let info = policy.info();
    if let Some(serving) = serving {
        if serving.task != info.task {
            return Err(HotLoadError::TaskChanged {
                name: name.to_owned(),
                serving: serving.task,
                published: info.task,
            });
        }
        // Callers act with the served shapes: new task arguments (more obstacles) or
        // other data must come under a new name.
        let shape = |p: &PolicyInfo| (p.observation_dim, p.action_dim);
        if shape(&serving) != shape(&info) {
            return Err(HotLoadError::ShapeChanged {
                name: name.to_owned(),
                serving: shape(&serving),
                published: shape(&info),
            });
        }
    }
    policies.insert(Arc::new(policy));
    Ok(info)
}

/// Refusals reported at most once per checkpoint key and kind per [`REPORT_INTERVAL`]:
/// a flood of rogue publications must not flood the engine's log.
#[derive(Default)]
pub(crate) struct RefusalLog(Mutex<HashMap<(String, &'static str), Report>>);

struct Report {
    at: Instant,
    suppressed: u64,
}

impl RefusalLog {
    /// `Some(n)` if this refusal is to be reported now, `n` being how many like it were
    /// suppressed since the last report; `None` to suppress it.
    pub fn admit(&self, key: &str, kind: &'static str, now: Instant) -> Option<u64> {
        let mut reports = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(report) = reports.get_mut(&(key.to_owned(), kind)) {
            if now.duration_since(report.at) < REPORT_INTERVAL {
                report.suppressed += 1;
                return None;
            }
            let suppressed = report.suppressed;
            *report = Report {
                at: now,
                suppressed: 0,
            };
            return Some(suppressed);
        }
        // Many keys (an attacker may invent names): forget those reported long ago.
        if reports.len() >= 1024 {
            reports.retain(|_, report| now.duration_since(report.at) < REPORT_INTERVAL);
        }
        reports.insert(
            (key.to_owned(), kind),
            Report {
                at: now,
                suppressed: 0,
            },
        );
        Some(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_is_reported_once_per_interval_with_the_count_it_suppressed() {
        let log = RefusalLog::default();
        let start = Instant::now();
        assert_eq!(log.admit("k", "signature", start), Some(0));
        for i in 1..=100 {
            assert_eq!(
                log.admit("k", "signature", start + Duration::from_millis(i)),
                None
            );
        }
        // Another key or kind is its own report.
        assert_eq!(log.admit("k", "decode", start), Some(0));
        assert_eq!(log.admit("other", "signature", start), Some(0));
        assert_eq!(
            log.admit("k", "signature", start + REPORT_INTERVAL),
            Some(100)
        );
        assert_eq!(log.admit("k", "signature", start + REPORT_INTERVAL), None);
    }
}
