//! `ciflow router`: host the Zenoh router that joins machines, optionally enforcing who
//! may serve, own sessions and publish policies.

use anyhow::Context;
use ciflow_bridge::{AccessPolicy, Router};

use ciflow_cli::network::NetworkArgs;

/// Run a Zenoh router (any `zenohd` does the same job). Every other process joins it as a
/// Zenoh client (`--connect tcp/<router>:7447`, or a `--config` file).
///
/// With names (`--engine`, `--trainer`, `--client`), only those may take part, each in
/// its role, recognised by the common name of its TLS client certificate: give a
/// configuration that listens on tls/ with `enable_mtls` (deploy/secure/README.md).
#[derive(clap::Args, Debug)]
pub struct RouterArgs {
    /// Zenoh flags (default: listen on tcp/127.0.0.1:7447).
    #[command(flatten)]
    pub network: NetworkArgs,
    #[command(flatten)]
    pub access: AccessPolicy,
}

pub fn run(args: RouterArgs) -> anyhow::Result<()> {
    let router =
        Router::open(&args.network.options()?, &args.access).context("starting the router")?;
    // Tests and scripts wait for this line before connecting.
    println!("ciflow router {} ready; {}", router.zid(), args.access);
    loop {
        // Routing happens on Zenoh's threads; this one only keeps the router alive.
        std::thread::park();
    }
}
