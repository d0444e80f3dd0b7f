//! Stepping in process, no Zenoh: the reference the served benchmarks measure themselves
//! against (the round-trip example, the scale-out and in-process-steps ones).

use std::time::Instant;

/// Env-steps per second of `envs` environments of the task called directly, split over
/// `threads` threads that step their share concurrently, one step each in turn: from a
/// reset (seeds `0..envs`), `untimed` steps per environment, then `timed` ones (with the
/// zero action of the served runs). One environment on one thread stays in cache and is
/// what the engine cannot beat per core; thousands on every core are what the engine
/// itself has to do.
pub fn in_process_rate(
    task: &str,
    envs: usize,
    threads: usize,
    (untimed, timed): (usize, usize),
) -> Result<f64, Box<dyn std::error::Error + Send + Sync>> {
    let options = ciflow_envs::ResetOptions::default();
    let mut batch = Vec::with_capacity(envs);
    for seed in 0..envs as u64 {
        let mut env = ciflow_envs::make(task)?;
        env.reset(Some(seed), &options)?;
        batch.push(env);
    }
    let action = vec![0.0; batch[0].spec().action_space.dim()];
    let share = envs.div_ceil(threads);
    // Fewer environments than threads make fewer shares: the barrier waits for those.
    let start = std::sync::Barrier::new(envs.div_ceil(share) + 1);
    let elapsed = std::thread::scope(|scope| {
        let workers: Vec<_> = batch
            .chunks_mut(share)
            .map(|envs| {
                let (start, action, options) = (&start, &action, &options);
                scope.spawn(move || -> Result<(), ciflow_envs::EnvError> {
                    // Into one buffer, as the engine steps its batches.
                    let mut observation = vec![0.0; envs[0].spec().observation_space.dim()];
                    let mut step_all = |rounds| {
                        for _ in 0..rounds {
                            for env in envs.iter_mut() {
                                let step = env.step_into(action, &mut observation)?;
                                if step.terminated || step.truncated {
                                    env.reset(None, options)?;
                                }
                            }
                        }
                        Ok(())
                    };
                    let warmed = step_all(untimed);
                    // Meet the others even after a failure, so that none waits forever.
                    start.wait();
                    warmed.and_then(|()| step_all(timed))
                })
            })
            .collect();
        start.wait();
        let clock = Instant::now();
        for worker in workers {
            worker.join().expect("a stepping thread panicked")?;
        }
        Ok::<_, ciflow_envs::EnvError>(clock.elapsed())
    })?;
    Ok((timed * envs) as f64 / elapsed.as_secs_f64())
}
