//! Hot-loading: a checkpoint published on `ciflow/v1/policies/<policy>/checkpoint`
//! replaces the policy served under that name, if it fits a task this engine serves and
//! keeps the policy's task.

use std::sync::Arc;

use super::policy_table::PolicyTable;
use crate::checkpoint_policy::{CheckpointPolicy, PolicyLoadError};
use crate::policy::Policy;
use crate::protocol::keys;
use crate::protocol::{CheckpointMsg, ErrorReply, PolicyInfo, decode_request};
use crate::task_factory::TaskFactory;

/// Why a publication was not served.
#[derive(Debug, thiserror::Error)]
pub enum HotLoadError {
    #[error("`{0}` is not a checkpoint key")]
    NotCheckpointKey(String),
    #[error("undecodable publication")]
    Decode(#[source] ErrorReply),
    #[error(transparent)]
    Load(#[from] PolicyLoadError),
    #[error("policy `{name}` acts in {serving}, the checkpoint in {published}")]
    TaskChanged {
        name: String,
        serving: String,
        published: String,
    },
}

/// Swaps the checkpoint published on `key` into `policies`; returns what is now served.
pub fn hot_load(
    policies: &PolicyTable,
    factories: &[TaskFactory],
    key: &str,
    payload: &[u8],
) -> Result<PolicyInfo, HotLoadError> {
    let name = keys::parse_policy_checkpoint(key)
        .ok_or_else(|| HotLoadError::NotCheckpointKey(key.to_owned()))?;
    let message: CheckpointMsg = decode_request(payload).map_err(HotLoadError::Decode)?;
    let current = policies.get(name);
    let kwargs = current
        .as_ref()
        .map(|p| p.task_kwargs())
        .unwrap_or_default();
    let policy = CheckpointPolicy::from_message(name, &message, factories, &kwargs)?;
    let info = policy.info();
    if let Some(current) = current
        && current.info().task != info.task
    {
        return Err(HotLoadError::TaskChanged {
            name: name.to_owned(),
            serving: current.info().task,
            published: info.task,
        });
    }
    policies.insert(Arc::new(policy));
    Ok(info)
}
