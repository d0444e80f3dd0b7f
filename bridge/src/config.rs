//! Zenoh configuration of engines and clients: standard Zenoh JSON5 files plus the usual
//! `--mode/--connect/--listen` overrides. With none of them, everything meets on the
//! well-known loopback endpoint [`DEFAULT_ENDPOINT`] without multicast, with a
//! [`LEASE_MS`] link lease.

use std::path::PathBuf;

use zenoh::{Config, Wait};

use crate::error::BridgeError;

/// Where a zero-configuration engine listens and a zero-configuration client connects,
/// unless [`DEFAULT_ENDPOINT_VARIABLE`] names another ([`default_endpoint`]).
pub const DEFAULT_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// The environment variable that moves the zero-configuration endpoint (the Python
/// package reads the same one), e.g. so that tests meet on a private port.
pub const DEFAULT_ENDPOINT_VARIABLE: &str = "CIFLOW_DEFAULT_ENDPOINT";

/// The zero-configuration endpoint: [`DEFAULT_ENDPOINT_VARIABLE`] if set, else
/// [`DEFAULT_ENDPOINT`].
pub fn default_endpoint() -> String {
    std::env::var(DEFAULT_ENDPOINT_VARIABLE)
        .ok()
        .filter(|endpoint| !endpoint.is_empty())
        .unwrap_or_else(|| DEFAULT_ENDPOINT.to_owned())
}

/// Where an engine that found the default endpoint taken listens itself: loopback, on a
/// port the system picks.
const JOINING_ENGINE_ENDPOINT: &str = "tcp/127.0.0.1:0";

/// The link lease every ciflow process announces (Zenoh's default is 10 s): a peer that
/// hears nothing from this process for that long drops its link, so an engine reclaims
/// the sessions of a frozen client (stopped process, dead machine) this long after it
/// froze, plus the moment it looks for the token again. Zenoh sends a keep-alive every
/// quarter lease.
pub const LEASE_MS: u64 = 3_000;

/// Zenoh's role for this process.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    Peer,
    Client,
    Router,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
            Mode::Router => "router",
        }
    }
}

impl std::str::FromStr for Mode {
    type Err = BridgeError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "peer" => Ok(Mode::Peer),
            "client" => Ok(Mode::Client),
            "router" => Ok(Mode::Router),
            other => Err(BridgeError::UnknownMode(other.to_owned())),
        }
    }
}

/// How to join Zenoh. Fields left empty keep the file's (or the default's) values.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NetworkOptions {
    /// A standard Zenoh JSON5 configuration file.
    pub config_file: Option<PathBuf>,
    pub mode: Option<Mode>,
    /// Endpoints to connect to, e.g. `tcp/10.0.0.2:7447` (a router or an engine).
    pub connect: Vec<String>,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// Who a client process is: the `<identity>` chunk of its keys (default
    /// [`ANONYMOUS`](crate::protocol::keys::ANONYMOUS)). Behind a router with access
    /// control it must be the name the router authenticates, e.g. the common name of the
    /// process's TLS certificate.
    pub identity: Option<String>,
}

/// Which side of the protocol a configuration is for: it decides the defaults.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Listens on [`DEFAULT_ENDPOINT`] in peer mode.
    Engine,
    /// Connects to [`DEFAULT_ENDPOINT`] in client mode and fails fast when nobody listens.
    Client,
    /// Listens on [`DEFAULT_ENDPOINT`] in router mode (the mode holds even with a file).
    Router,
}

impl NetworkOptions {
    /// Options that connect to (or, for an engine, listen on) one endpoint.
    pub fn endpoint(role: Role, endpoint: &str) -> Self {
        let mut options = Self::default();
        match role {
            Role::Engine | Role::Router => options.listen.push(endpoint.to_owned()),
            Role::Client => options.connect.push(endpoint.to_owned()),
        }
        options
    }

    /// The endpoints an engine with these options listens on, as far as the options say:
    /// those given, else [`DEFAULT_ENDPOINT`] without a file (with one, the file's, not
    /// listed here).
    pub fn engine_endpoints(&self) -> Vec<String> {
        match (self.listen.is_empty(), &self.config_file) {
            (true, None) => vec![default_endpoint()],
            _ => self.listen.clone(),
        }
    }

    /// Whether nothing was configured: no file, mode or endpoint (what a second engine
    /// on one machine may join the first through, see [`NetworkOptions::joining_default`]).
    pub fn is_default(&self) -> bool {
        self.config_file.is_none()
            && self.mode.is_none()
            && self.connect.is_empty()
            && self.listen.is_empty()
    }

    /// An engine's options to join the engine (or router) already listening on the
    /// default endpoint: connect to it as a peer, which routes the joiner's queries
    /// for the clients of the first, and listen on a loopback port of the system's
    /// choosing. So engines started with no options on one machine all meet.
    pub fn joining_default(&self) -> Self {
        Self {
            connect: vec![default_endpoint()],
            listen: vec![JOINING_ENGINE_ENDPOINT.to_owned()],
            ..self.clone()
        }
    }

    /// A Zenoh session for `role` with these options; a failure says what was being done
    /// (`action`) and what to check (`hint`).
    pub(crate) fn open(
        &self,
        role: Role,
        action: &'static str,
        hint: &'static str,
    ) -> Result<zenoh::Session, BridgeError> {
        let config = self.to_zenoh_config(role)?;
        zenoh::open(config)
            .wait()
            .map_err(|source| BridgeError::Open {
                action,
                hint,
                source: source.into(),
            })
    }

    /// The Zenoh configuration for `role`.
    ///
    /// Without a file: multicast scouting off; an engine is a peer listening on
    /// [`DEFAULT_ENDPOINT`] (or `listen`), a client is a Zenoh client connecting to
    /// [`DEFAULT_ENDPOINT`] (or `connect`) that sends through the socket and reads what
    /// others send through shared memory. With a file, only the explicit overrides apply.
    pub fn to_zenoh_config(&self, role: Role) -> Result<Config, BridgeError> {
        let mut config = match &self.config_file {
            Some(path) => Config::from_file(path).map_err(|source| BridgeError::ConfigFile {
                path: path.clone(),
                source: source.into(),
            })?,
            None => default_config(role)?,
        };
        if role == Role::Router {
            if let Some(mode) = self.mode.filter(|mode| *mode != Mode::Router) {
                return Err(BridgeError::InvalidArgument(format!(
                    "a router runs in Zenoh's router mode, not {}",
                    mode.as_str()
                )));
            }
            insert(&mut config, "mode", &json_string(Mode::Router.as_str()))?;
        } else if let Some(mode) = self.mode {
            insert(&mut config, "mode", &json_string(mode.as_str()))?;
        }
        if !self.connect.is_empty() {
            insert(&mut config, "connect/endpoints", &json_list(&self.connect))?;
        }
        if !self.listen.is_empty() {
            insert(&mut config, "listen/endpoints", &json_list(&self.listen))?;
        }
        Ok(config)
    }
}

/// Whether Zenoh sends messages of 3 KiB or more through a shared-memory pool of its own.
const SEND_THROUGH_POOL: &str = "transport/shared_memory/transport_optimization/enabled";

fn default_config(role: Role) -> Result<Config, BridgeError> {
    let mut config = Config::default();
    insert(&mut config, "scouting/multicast/enabled", "false")?;
    insert(
        &mut config,
        "transport/link/tx/lease",
        &LEASE_MS.to_string(),
    )?;
    let endpoint = json_list(&[default_endpoint()]);
    match role {
        Role::Engine => {
            insert(&mut config, "mode", &json_string(Mode::Peer.as_str()))?;
            insert(&mut config, "listen/endpoints", &endpoint)?;
        }
        // The mode is set by `to_zenoh_config`, with or without a file.
        Role::Router => insert(&mut config, "listen/endpoints", &endpoint)?,
        Role::Client => {
            insert(&mut config, "mode", &json_string(Mode::Client.as_str()))?;
            insert(&mut config, "connect/endpoints", &endpoint)?;
            // A client reads the engine's pool but sends through the socket: Zenoh never
            // unmaps a segment it has read from, so a long-running engine would keep
            // every client's 16 MiB pool in tmpfs for good, and on a 64 MiB `/dev/shm`
            // (Docker's default) the fourth client could not open a session.
            insert(&mut config, SEND_THROUGH_POOL, "false")?;
        }
    }
    Ok(config)
}

fn insert(config: &mut Config, key: &str, json5: &str) -> Result<(), BridgeError> {
    config
        .insert_json5(key, json5)
        .map_err(|source| BridgeError::ConfigSetting {
            key: key.to_owned(),
            value: json5.to_owned(),
            source: source.into(),
        })
}

fn json_string(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| json_string(s)).collect();
    format!("[{}]", quoted.join(","))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_router_refuses_any_other_mode() {
        let asked = |mode| NetworkOptions {
            mode: Some(mode),
            ..NetworkOptions::default()
        };
        assert!(asked(Mode::Router).to_zenoh_config(Role::Router).is_ok());
        let refused = asked(Mode::Client)
            .to_zenoh_config(Role::Router)
            .unwrap_err();
        assert!(
            refused.to_string().contains("router mode, not client"),
            "{refused}"
        );
        assert!(asked(Mode::Client).to_zenoh_config(Role::Engine).is_ok());
    }

    #[test]
    fn an_engine_reports_the_endpoints_it_was_told_or_the_default() {
        assert_eq!(
            NetworkOptions::default().engine_endpoints(),
            [DEFAULT_ENDPOINT]
        );
        let given = NetworkOptions::endpoint(Role::Engine, "tcp/127.0.0.1:1");
        assert_eq!(given.engine_endpoints(), ["tcp/127.0.0.1:1"]);
        let from_file = NetworkOptions {
            config_file: Some("zenoh.json5".into()),
            ..NetworkOptions::default()
        };
        assert!(from_file.engine_endpoints().is_empty());
    }

    #[test]
    fn a_second_default_engine_joins_the_first_and_listens_on_a_free_loopback_port() {
        let default = NetworkOptions::default();
        assert!(default.is_default());
        let joining = default.joining_default();
        assert!(!joining.is_default());
        assert_eq!(joining.connect, [default_endpoint()]);
        assert_eq!(joining.listen, [JOINING_ENGINE_ENDPOINT]);
        let config = joining.to_zenoh_config(Role::Engine).unwrap();
        assert!(config.get_json("mode").unwrap().contains("peer"));
        for configured in [
            NetworkOptions::endpoint(Role::Engine, "tcp/127.0.0.1:1"),
            NetworkOptions {
                mode: Some(Mode::Client),
                ..NetworkOptions::default()
            },
        ] {
            assert!(!configured.is_default(), "{configured:?}");
        }
    }

    #[test]
    fn defaults_meet_on_the_loopback_endpoint() {
        let engine = NetworkOptions::default()
            .to_zenoh_config(Role::Engine)
            .unwrap();
        assert!(
            engine
                .get_json("listen/endpoints")
                .unwrap()
                .contains(DEFAULT_ENDPOINT)
        );
        assert_eq!(engine.get_json("mode").unwrap(), "\"peer\"");
        assert_eq!(
            engine.get_json("scouting/multicast/enabled").unwrap(),
            "false"
        );
        let client = NetworkOptions::default()
            .to_zenoh_config(Role::Client)
            .unwrap();
        assert!(
            client
                .get_json("connect/endpoints")
                .unwrap()
                .contains(DEFAULT_ENDPOINT)
        );
        assert_eq!(client.get_json("mode").unwrap(), "\"client\"");
        for config in [engine, client] {
            assert_eq!(
                config.get_json("transport/link/tx/lease").unwrap(),
                LEASE_MS.to_string()
            );
        }
    }

    #[test]
    fn overrides_replace_defaults_and_bad_values_are_errors() {
        let options = NetworkOptions {
            mode: Some(Mode::Peer),
            connect: vec!["tcp/10.1.2.3:7447".into()],
            ..Default::default()
        };
        let config = options.to_zenoh_config(Role::Client).unwrap();
        assert!(
            config
                .get_json("connect/endpoints")
                .unwrap()
                .contains("10.1.2.3")
        );
        assert_eq!(config.get_json("mode").unwrap(), "\"peer\"");

        let bad = NetworkOptions {
            listen: vec!["not an endpoint".into()],
            ..Default::default()
        };
        assert!(bad.to_zenoh_config(Role::Engine).is_err());
        assert!("satellite".parse::<Mode>().is_err());
    }
}
