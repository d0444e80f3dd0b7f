//! Env-steps per second of `NUM_ENVS` environments of a task stepped in this process, no
//! Zenoh, split over `THREADS` threads that each step their share free-running, never
//! waiting for the others (zero actions, autoreset, `STEPS` timed steps each after one
//! untimed); prints `{"task", "num_envs", "threads", "env_steps_per_s"}` as one JSON line.
//! `bench/scale_out.py` runs it on one and two threads beside the engines it spreads the
//! same environments over: what two cores give, without serving and without waiting for
//! each other, bounds what two engines can.
//!
//! ```text
//! cargo run --release -p ciflow-bridge --example in_process_steps -- TASK NUM_ENVS THREADS STEPS
//! ```

#[path = "support/in_process.rs"]
mod in_process;

fn main() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [task, num_envs, threads, steps] = &args[..] else {
        return Err("usage: in_process_steps TASK NUM_ENVS THREADS STEPS".into());
    };
    let (num_envs, threads, steps): (usize, usize, usize) =
        (num_envs.parse()?, threads.parse()?, steps.parse()?);
    if num_envs == 0 || threads == 0 || steps == 0 {
        return Err("NUM_ENVS, THREADS and STEPS must be positive".into());
    }
    let rate = in_process::in_process_rate(
        task,
        num_envs,
        threads,
        (1, steps),
        in_process::Pace::FreeRunning,
    )?;
    println!(
        "{{\"task\": \"{task}\", \"num_envs\": {num_envs}, \"threads\": {threads}, \
         \"env_steps_per_s\": {rate:.1}}}"
    );
    Ok(())
}
