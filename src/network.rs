//! How a command joins Zenoh: the flags every networked command takes, and those of the
//! commands that can run their work on engines (`evaluate`, `stability`).

use std::path::{Path, PathBuf};

use anyhow::Context;
use ciflow_bridge::{CheckpointSigner, Client, Kwargs, Mode, NetworkOptions, spread};

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

/// `--engines` and what it needs: run the work on engines instead of in this process.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct EnginesArgs {
    /// Run on these engines instead of in this process: names, comma-separated, or `*` for
    /// every engine reachable on Zenoh. The checkpoint is published to them; the report
    /// equals the in-process one.
    #[arg(long, value_delimiter = ',', value_name = "ENGINES")]
    pub engines: Vec<String>,
    /// With --engines: sign the published checkpoint with this ed25519 private key (PKCS#8
    /// PEM), for engines that load only signed checkpoints (`ciflow serve --trusted-key`).
    #[arg(long, value_name = "PEM", requires = "engines")]
    pub signing_key: Option<PathBuf>,
    #[command(flatten)]
    pub network: NetworkArgs,
}

/// Engines serving a checkpoint, ready for [`spread`]'s work.
pub struct OnEngines {
    pub client: Client,
    pub engines: Vec<String>,
    /// The name the checkpoint is served under.
    pub policy: String,
}

impl EnginesArgs {
    /// Joins Zenoh, finds the engines that serve `task` and hands them the checkpoint
    /// `dir` of that task, built with `kwargs`; `None` without `--engines`.
    pub fn serve_checkpoint(
        &self,
        dir: &Path,
        task: &str,
        kwargs: &Kwargs,
    ) -> anyhow::Result<Option<OnEngines>> {
        if self.engines.is_empty() {
            return Ok(None);
        }
        let client = Client::open(&self.network.options()?).context("joining Zenoh")?;
        let engines = spread::resolve_engines(&client, &self.engines, task)?;
        let signer = self
            .signing_key
            .as_deref()
            .map(CheckpointSigner::from_pem_file)
            .transpose()
            .context("--signing-key")?;
        let policy = spread::load_checkpoint(&client, &engines, dir, kwargs, signer)
            .context("handing the checkpoint to the engines")?;
        eprintln!("on {} engine(s): {}", engines.len(), engines.join(", "));
        Ok(Some(OnEngines {
            client,
            engines,
            policy,
        }))
    }
}
