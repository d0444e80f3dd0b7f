//! How a command joins Zenoh: the flags every networked command takes.

use std::path::PathBuf;

use ciflow_bridge::{Mode, NetworkOptions};

/// Zenoh flags. With none, the zero-configuration loopback default applies (an engine
/// listens on tcp/127.0.0.1:7447, everything else connects there).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct NetworkArgs {
    /// Standard Zenoh JSON5 configuration file.
    #[arg(long, env = "CIFLOW_ZENOH_CONFIG")]
    pub config: Option<PathBuf>,
    /// Zenoh mode (peer, client or router).
    #[arg(long)]
    pub mode: Option<String>,
    /// Endpoint to connect to, e.g. tcp/10.0.0.2:7447 (repeatable).
    #[arg(long)]
    pub connect: Vec<String>,
    /// Endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable).
    #[arg(long)]
    pub listen: Vec<String>,
    /// Who this process is (default anonymous); behind a router with access control, the
    /// name the router authenticates (deploy/secure/README.md).
    #[arg(long, env = "CIFLOW_IDENTITY")]
    pub identity: Option<String>,
}

impl NetworkArgs {
    pub fn options(&self) -> anyhow::Result<NetworkOptions> {
        Ok(NetworkOptions {
            config_file: self.config.clone(),
            mode: self.mode.as_deref().map(str::parse::<Mode>).transpose()?,
            connect: self.connect.clone(),
            listen: self.listen.clone(),
            identity: self.identity.clone(),
        })
    }
}
