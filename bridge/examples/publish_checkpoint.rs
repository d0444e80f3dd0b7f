//! Hand a checkpoint to every running engine: the engines hot-load it under the policy's
//! name (`ciflow/v2/policies/<name>/checkpoint`) and serve it on `…/policy/<name>/act`,
//! without a restart. `ciflow train --publish NAME` does this after every better epoch.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example publish_checkpoint -- \
//!     ENDPOINT CHECKPOINT_DIR NAME
//! ```
//! A publication reaches only the engines already listening, so the example publishes,
//! asks the engines what they serve, and publishes again until one serves the policy.

use std::path::PathBuf;
use std::time::Duration;

use ciflow_bridge::{CheckpointPublisher, Client, NetworkOptions, Role};

const ATTEMPTS: usize = 40;
const WAIT: Duration = Duration::from_millis(250);

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [endpoint, dir, name] = args.as_slice() else {
        return Err("usage: publish_checkpoint ENDPOINT CHECKPOINT_DIR NAME".into());
    };
    let network = NetworkOptions::endpoint(Role::Client, endpoint);
    let publisher = CheckpointPublisher::open(&network, name)?;
    let client = Client::open(&network)?;
    for _ in 0..ATTEMPTS {
        publisher.publish(&PathBuf::from(dir), 0, f64::NAN)?;
        std::thread::sleep(WAIT);
        for engine in client.discover()? {
            if let Some(policy) = engine.policies.iter().find(|p| &p.name == name) {
                println!(
                    "engine {} serves policy `{}` for {} ({} observations → {} actions)",
                    engine.name,
                    policy.name,
                    policy.task,
                    policy.observation_dim,
                    policy.action_dim
                );
                return Ok(());
            }
        }
    }
    Err(format!("no engine served policy `{name}` after {ATTEMPTS} publications").into())
}
