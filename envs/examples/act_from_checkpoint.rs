//! Act from a checkpoint in-process, without Zenoh: load the policy, build its task, and
//! let the policy choose every desired acceleration `q̈_des` until the episode ends.
//!
//! ```text
//! cargo run --release -p ciflow-envs --example act_from_checkpoint -- CHECKPOINT_DIR
//! ```
//! The checkpoint (e.g. a `ciflow train` output) names its task, built here with its
//! default arguments.

use std::path::PathBuf;

use ciflow_envs::actor::{Actor, DEFAULT_VELOCITY_GAIN, Model};
use ciflow_envs::env::SUCCESS_INFO;
use ciflow_envs::{ResetOptions, registry};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir] = args.as_slice() else {
        return Err("usage: act_from_checkpoint CHECKPOINT_DIR".into());
    };
    let model = Model::load(&PathBuf::from(dir), None)?;
    let mut env = registry::make(model.task())?;
    let mut actor = Actor::new(&model, env.spec(), DEFAULT_VELOCITY_GAIN)?;

    let (mut observation, _) = env.reset(Some(0), &ResetOptions::default())?;
    let mut action = vec![0.0; env.spec().action_space.dim()];
    let (mut steps, mut total_reward) = (0, 0.0);
    loop {
        actor.act(&observation, &mut action)?;
        let step = env.step(&action)?;
        (steps, total_reward) = (steps + 1, total_reward + step.reward);
        observation = step.observation;
        if step.terminated || step.truncated {
            let success = step.info.get(SUCCESS_INFO).copied() == Some(1.0);
            println!(
                "{} with `{}`: {steps} steps, return {total_reward:.3}, success {success}",
                model.task(),
                env.spec().id
            );
            return Ok(());
        }
    }
}
