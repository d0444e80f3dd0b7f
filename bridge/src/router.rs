//! A Zenoh router hosted in this process: the hub every ciflow process joins in `client`
//! mode to meet across machines, optionally enforcing an [`AccessPolicy`].
//!
//! Any Zenoh router works (`zenohd` with the same configuration file); this one saves
//! installing it and writes the access-control rules from the policy's names.

use zenoh::Wait;

use crate::access::AccessPolicy;
use crate::config::{NetworkOptions, Role};
use crate::error::BridgeError;

/// A running router; it stops when dropped.
pub struct Router {
    zsession: zenoh::Session,
}

impl Router {
    /// Starts a router with `network`'s configuration (default: listen on
    /// [`crate::DEFAULT_ENDPOINT`]). With a non-empty `access`, only the processes it names
    /// may take part, each in its role; peers are then recognised by their TLS client
    /// certificates, so the configuration must listen only on `quic/` (or `tls/`)
    /// endpoints with `transport/link/tls/enable_mtls` set.
    pub fn open(network: &NetworkOptions, access: &AccessPolicy) -> Result<Self, BridgeError> {
        let mut config = network.to_zenoh_config(Role::Router)?;
        if !access.is_empty() {
            require_client_certificates(&config)?;
            let rules = access.to_json()?;
            config
                .insert_json5("access_control", &rules)
                .map_err(|source| BridgeError::ConfigSetting {
                    key: "access_control".into(),
                    value: rules,
                    source: source.into(),
                })?;
        }
        let zsession = zenoh::open(config)
            .wait()
            .map_err(|source| BridgeError::Open {
                action: "start the router",
                hint: "is its endpoint free, and are the certificate files readable?",
                source: source.into(),
            })?;
        Ok(Self { zsession })
    }

    /// The router's Zenoh id.
    pub fn zid(&self) -> String {
        self.zsession.zid().to_string()
    }
}

/// Access control names peers by their certificates' common names: without client
/// certificates on every endpoint, no peer would have a name and every rule would be moot.
fn require_client_certificates(config: &zenoh::Config) -> Result<(), BridgeError> {
    let json = config.get_json("listen/endpoints").unwrap_or_default();
    let endpoints: Vec<String> = serde_json::from_str(&json).unwrap_or_default();
    let with_certificates = !endpoints.is_empty()
        && endpoints
            .iter()
            .all(|e| e.starts_with("quic/") || e.starts_with("tls/"));
    let mtls = config
        .get_json("transport/link/tls/enable_mtls")
        .is_ok_and(|v| v == "true");
    if with_certificates && mtls {
        Ok(())
    } else {
        Err(BridgeError::InvalidArgument(format!(
            "access control recognises peers by their TLS client certificates: listen only \
             on quic/ (or tls/) endpoints (now {json}) and set transport/link/tls/enable_mtls, \
             root_ca_certificate, listen_certificate and listen_private_key in the Zenoh \
             configuration (see deploy/secure/README.md)"
        )))
    }
}
