//! Push a running environment and watch it recover: two obstacle-avoidance sessions,
//! reset with the same seed (same obstacles, target and start), both driven by the task's
//! expert; the second is pushed sideways for 0.2 s. Prints how far apart they are during
//! and after the push.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example perturb_session -- [ENDPOINT]
//! ```
//! The engine runs in this process (as in `serve_and_step`); against a `ciflow serve`
//! elsewhere, open only the client.

use std::collections::BTreeMap;

use ciflow_bridge::protocol::{PerturbationKindMsg, PerturbationMsg};
use ciflow_bridge::{Client, EngineServer, NetworkOptions, Role, ServerOptions};

const STEPS: usize = 150;
const PUSH_AT_STEP: usize = 20;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let endpoint = std::env::args().nth(1);
    let endpoint = endpoint
        .as_deref()
        .unwrap_or(ciflow_bridge::DEFAULT_ENDPOINT);
    let engine = EngineServer::open(
        &NetworkOptions::endpoint(Role::Engine, endpoint),
        ServerOptions::default(),
    )?;
    let client = Client::open(&NetworkOptions::endpoint(Role::Client, endpoint))?;
    let make = || client.make(engine.name(), "ciflow/Obstacle-v0", 1, &BTreeMap::new());
    let (calm, pushed) = (make()?, make()?);
    let seed = 7;
    calm.reset(Some(seed), None)?;
    pushed.reset(Some(seed), None)?;

    let mut largest_gap: f64 = 0.0;
    for step in 0..STEPS {
        if step == PUSH_AT_STEP {
            // 3 N along y on the point mass (link 0) for 0.2 s, starting now.
            let push = PerturbationMsg {
                kind: PerturbationKindMsg::LinkWrench {
                    link: 0,
                    force: [0.0, 3.0, 0.0],
                    torque: [0.0; 3],
                },
                start: None,
                duration: 0.2,
            };
            let time = pushed.control().perturb(0, push)?;
            println!("pushed the second environment at t = {time:.2} s");
        }
        let a = calm.step(&calm.expert(0)?)?.observation;
        let b = pushed.step(&pushed.expert(0)?)?.observation;
        let gap = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
        largest_gap = largest_gap.max(gap);
        if step % 15 == 0 || step == STEPS - 1 {
            println!("step {step:3}: distance between the two {gap:.4} m");
        }
    }
    println!("largest distance {largest_gap:.4} m");
    calm.close()?;
    pushed.close()?;
    Ok(())
}
