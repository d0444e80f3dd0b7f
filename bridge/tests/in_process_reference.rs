//! The benchmarks' in-process reference (`examples/support/in_process.rs`) ends for any
//! split of environments over threads, fewer environments than threads included (it once
//! waited forever for a thread that had no share), and refuses an unknown task.

#[path = "../examples/support/in_process.rs"]
mod in_process;

use in_process::{Pace, in_process_rate};

#[test]
fn every_split_of_environments_over_threads_ends_with_a_rate() {
    for pace in [Pace::Lockstep, Pace::FreeRunning] {
        for (envs, threads) in [(1, 1), (1, 2), (3, 2), (5, 4), (8, 2)] {
            let rate = in_process_rate("ciflow/LimitCycle-v0", envs, threads, (1, 20), pace)
                .unwrap_or_else(|e| {
                    panic!("{envs} environments on {threads} threads, {pace:?}: {e}")
                });
            assert!(
                rate.is_finite() && rate > 0.0,
                "{envs} environments on {threads} threads, {pace:?}: {rate} env-steps/s"
            );
        }
    }
}

#[test]
fn an_unknown_task_is_an_error() {
    let error = in_process_rate("ciflow/Nothing-v0", 2, 2, (0, 1), Pace::Lockstep).unwrap_err();
    assert!(error.to_string().contains("Nothing"), "{error}");
}
