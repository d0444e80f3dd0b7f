//! `ciflow serve`: host every task as Gymnasium environments over Zenoh.

use anyhow::Context;
use ciflow_bridge::{EngineServer, ServerOptions};

use super::network::NetworkArgs;

/// Start an engine that hosts environment sessions for Zenoh clients (Python
/// `gymnasium.make("ciflow/...")`, or any Zenoh client following bridge/PROTOCOL.md).
///
/// With no flags it listens on tcp/127.0.0.1:7447 as a Zenoh peer without multicast, which
/// is where clients on this machine look. To serve other machines, pass `--listen
/// tcp/0.0.0.0:7447`, or join a Zenoh router with `--connect tcp/<router>:7447` (or a
/// standard Zenoh JSON5 file with `--config`).
#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// Zenoh flags (default: listen on tcp/127.0.0.1:7447).
    #[command(flatten)]
    pub network: NetworkArgs,
    /// Engine name used in key expressions (default: the Zenoh session id).
    #[arg(long)]
    pub name: Option<String>,
    /// Most telemetry samples per second and session.
    #[arg(long, default_value_t = 60.0)]
    pub telemetry_hz: f64,
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    let network = args.network.options()?;
    anyhow::ensure!(
        args.telemetry_hz.is_finite() && args.telemetry_hz > 0.0,
        "--telemetry-hz must be a positive number"
    );
    let options = ServerOptions {
        name: args.name,
        telemetry_hz: args.telemetry_hz,
        ..ServerOptions::default()
    };
    let task_ids: Vec<String> = options.tasks.iter().map(|t| t.id.clone()).collect();
    let server = EngineServer::open(&network, options).context("starting the engine")?;
    let endpoints = if network.listen.is_empty() && network.config_file.is_none() {
        vec![ciflow_bridge::DEFAULT_ENDPOINT.to_owned()]
    } else {
        network.listen.clone()
    };
    // Tests and scripts wait for this line before connecting.
    println!(
        "ciflow engine `{}` ready on [{}] serving {}",
        server.name(),
        endpoints.join(", "),
        task_ids.join(", ")
    );
    loop {
        // Serving happens on Zenoh's threads; this one only keeps the engine alive until
        // the process is stopped.
        std::thread::park();
    }
}
