//! The policies an engine serves.

use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};

use crate::policy::Policy;
use crate::protocol::PolicyInfo;

/// The policies an engine serves, by name. A hot-loaded checkpoint replaces its name's
/// entry atomically; callers holding the old `Arc` finish with it.
#[derive(Default)]
pub(crate) struct PolicyTable(RwLock<BTreeMap<String, Arc<dyn Policy>>>);

impl PolicyTable {
    pub fn get(&self, name: &str) -> Option<Arc<dyn Policy>> {
        self.0
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .get(name)
            .cloned()
    }

    pub fn insert(&self, policy: Arc<dyn Policy>) {
        let name = policy.info().name;
        self.0
            .write()
            .unwrap_or_else(|p| p.into_inner())
            .insert(name, policy);
    }

    pub fn names(&self) -> Vec<String> {
        self.0
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .keys()
            .cloned()
            .collect()
    }

    pub fn infos(&self) -> Vec<PolicyInfo> {
        self.0
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .values()
            .map(|p| p.info())
            .collect()
    }
}
