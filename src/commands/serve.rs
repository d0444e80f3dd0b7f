//! `ciflow serve`: host every task as Gymnasium environments over Zenoh.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use ciflow_bridge::{
    CheckpointPolicy, EngineServer, Kwargs, Policy, PolicyLoadError, ServerOptions,
    default_endpoint, scheduling,
};
use ciflow_envs::actor::Model;

use ciflow_cli::network::NetworkArgs;
use ciflow_cli::parse::{parse_named_dir, parse_number_pair};

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
    /// A trained checkpoint to serve, `[NAME=]DIR` (repeatable; NAME defaults to the
    /// checkpoint's task). Clients evaluate it with `act` and let it drive sessions with
    /// `run`; a trainer's publications under the same name replace it without a restart.
    #[arg(long = "policy", value_name = "[NAME=]DIR", value_parser = parse_named_dir)]
    pub policies: Vec<(Option<String>, PathBuf)>,
    /// A checkpoint trained on data from elsewhere (`ciflow train --state`) to serve on its
    /// own observations `[q, q̇, c]`, with no task environment, `[NAME=]DIR` (repeatable):
    /// clients evaluate it with `act` (`ciflow.Policy(NAME).act(observation)`).
    #[arg(long = "own-data-policy", value_name = "[NAME=]DIR", value_parser = parse_named_dir)]
    pub own_data_policies: Vec<(Option<String>, PathBuf)>,
    /// Construction argument of the policies' task, as given to `ciflow demos --kwarg`
    /// when the checkpoint's data was made (e.g. obstacles=1; repeatable). Without any,
    /// each checkpoint's own recorded arguments apply.
    #[arg(
        long = "policy-kwarg",
        value_name = "NAME=VALUE",
        value_parser = parse_number_pair,
        requires = "policies"
    )]
    pub policy_kwargs: Vec<(String, f64)>,
    #[command(flatten)]
    pub limits: ciflow_bridge::Limits,
    #[command(flatten)]
    pub trust: ciflow_bridge::signing::TrustArgs,
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    // Before any thread starts, so that all of the engine's inherit it.
    if let Err(error) = scheduling::run_as_batch() {
        eprintln!("ciflow serve: running with the default scheduling policy ({error})");
    }
    let network = args.network.options()?;
    let mut options = ServerOptions {
        name: args.name,
        telemetry_hz: args.telemetry_hz,
        limits: args.limits,
        trusted_keys: args.trust.load()?,
        ..ServerOptions::default()
    };
    let kwargs: Kwargs = args
        .policy_kwargs
        .into_iter()
        .map(|(name, value)| (name, value.into()))
        .collect();
    let in_task = args.policies.iter().map(|(name, dir)| {
        let loaded = CheckpointPolicy::load(name.as_deref(), dir, &options.tasks, &kwargs);
        let hint = match loaded {
            Err(PolicyLoadError::Shape(_)) => {
                " (a checkpoint trained on data from elsewhere is served with --own-data-policy)"
            }
            _ => "",
        };
        loaded.with_context(|| format!("loading the policy --policy {}{hint}", dir.display()))
    });
    let on_own_data = args.own_data_policies.iter().map(|(name, dir)| {
        Model::load(dir, None)
            .map_err(PolicyLoadError::from)
            .and_then(|model| CheckpointPolicy::on_own_data(name.as_deref(), model))
            .with_context(|| format!("loading the policy --own-data-policy {}", dir.display()))
    });
    options.policies = in_task
        .chain(on_own_data)
        .map(|policy| anyhow::Ok(Arc::new(policy?) as Arc<dyn Policy>))
        .collect::<anyhow::Result<_>>()?;
    let policy_names: Vec<String> = options.policies.iter().map(|p| p.info().name).collect();
    let task_ids: Vec<String> = options.tasks.iter().map(|t| t.id.clone()).collect();
    let server = EngineServer::open(&network, options).context("starting the engine")?;
    let endpoints = if server.joined() {
        // Clients of the engine already there reach this one through it.
        vec![format!("{} (joined the engine there)", default_endpoint())]
    } else {
        network.engine_endpoints()
    };
    // Tests and scripts wait for this line before connecting.
    println!(
        "ciflow engine `{}` ready on [{}] serving {}; policies: [{}]",
        server.name(),
        endpoints.join(", "),
        task_ids.join(", "),
        policy_names.join(", ")
    );
    loop {
        // Serving happens on Zenoh's threads; this one only keeps the engine alive until
        // the process is stopped.
        std::thread::park();
    }
}
