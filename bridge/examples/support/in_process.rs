//! Stepping in process, no Zenoh: the reference the served benchmarks measure themselves
//! against (the round-trip example, the scale-out and in-process-steps ones).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// How the threads stepping a batch in process keep pace with one another.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pace {
    /// As a synchronous vector environment (Gymnasium's, an engine's `step_batch`) steps:
    /// every environment takes step `k` before any takes step `k + 1`, because the actions
    /// of step `k + 1` are chosen from all the observations of step `k`. The threads meet
    /// at a spinning barrier after each step: a sleeping one would wait to be woken, which
    /// costs more than its share of a step on a small virtual machine.
    Lockstep,
    /// Each thread steps its share all the steps through without waiting for the others:
    /// faster than any synchronous batch (no thread ever waits for the slowest), so an
    /// upper bound.
    FreeRunning,
}

/// Env-steps per second of `envs` environments of the task called directly, split over
/// `threads` threads that step their share concurrently, paced as `pace` says: from a
/// reset (seeds `0..envs`), `untimed` steps per environment, then `timed` ones (with the
/// zero action of the served runs). One environment on one thread stays in cache and is
/// what the engine cannot beat per core; thousands on every core are what the engine
/// itself has to do.
pub fn in_process_rate(
    task: &str,
    envs: usize,
    threads: usize,
    (untimed, timed): (usize, usize),
    pace: Pace,
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
    // Fewer environments than threads make fewer shares: the barriers wait for those.
    let shares = envs.div_ceil(share);
    let start = std::sync::Barrier::new(shares + 1);
    let each_step = SpinBarrier::new(shares);
    let elapsed = std::thread::scope(|scope| {
        let workers: Vec<_> = batch
            .chunks_mut(share)
            .map(|envs| {
                let (start, each_step, action, options) = (&start, &each_step, &action, &options);
                scope.spawn(move || -> Result<(), ciflow_envs::EnvError> {
                    // Into one buffer each, as the engine steps its batches.
                    let mut observation = vec![0.0; envs[0].spec().observation_space.dim()];
                    let mut info = ciflow_envs::Info::new();
                    // After a failure the thread steps no more but still meets the
                    // others at every barrier, so that none of them waits forever.
                    let mut failure = None;
                    let mut step_all = |rounds| {
                        for _ in 0..rounds {
                            if failure.is_none() {
                                failure = envs
                                    .iter_mut()
                                    .try_for_each(|env| {
                                        let step =
                                            env.step_into(action, &mut observation, &mut info)?;
                                        if step.terminated || step.truncated {
                                            env.reset(None, options)?;
                                        }
                                        Ok::<_, ciflow_envs::EnvError>(())
                                    })
                                    .err();
                            }
                            if pace == Pace::Lockstep {
                                each_step.wait();
                            }
                        }
                    };
                    step_all(untimed);
                    start.wait();
                    step_all(timed);
                    failure.map_or(Ok(()), Err)
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

/// A barrier that spins (yielding the core after a while, in case the threads outnumber
/// the cores) instead of sleeping.
struct SpinBarrier {
    parties: usize,
    arrived: AtomicUsize,
    /// Meetings completed: a waiter leaves when it changes.
    meetings: AtomicUsize,
}

impl SpinBarrier {
    fn new(parties: usize) -> Self {
        Self {
            parties,
            arrived: AtomicUsize::new(0),
            meetings: AtomicUsize::new(0),
        }
    }

    fn wait(&self) {
        const SPINS_BEFORE_YIELDING: u32 = 1 << 12;
        let meeting = self.meetings.load(Ordering::Acquire);
        if self.arrived.fetch_add(1, Ordering::AcqRel) + 1 == self.parties {
            self.arrived.store(0, Ordering::Relaxed);
            self.meetings.fetch_add(1, Ordering::Release);
            return;
        }
        let mut spins = 0u32;
        while self.meetings.load(Ordering::Acquire) == meeting {
            if spins < SPINS_BEFORE_YIELDING {
                spins += 1;
                std::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
    }
}
