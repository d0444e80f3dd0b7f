//! `Env::step_into`, the step an engine runs for every environment of a batch: it gives
//! what `Env::step` gives, refuses a buffer of the wrong length before anything moves,
//! and allocates nothing once its info has room, so that thousands of environments
//! stepped on every core do not meet in the allocator.
//!
//! The heap allocations of this thread are counted by this test binary's global allocator
//! ([`ciflow_engine::allocations`]).

use ciflow_engine::allocations::{CountingAllocator, count_allocations};
use ciflow_envs::info::INLINE;
use ciflow_envs::{Env, EnvError, Info, ResetOptions, tasks};

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

/// Every task, reset with seed `seed`.
fn every_task(seed: u64) -> Vec<(&'static str, Box<dyn Env>)> {
    tasks()
        .iter()
        .map(|task| {
            let mut env = (task.make)();
            env.reset(Some(seed), &ResetOptions::default()).unwrap();
            (task.name, env)
        })
        .collect()
}

/// A small non-zero action, inside every task's action space.
fn action_of(env: &dyn Env) -> Vec<f64> {
    let dim = env.spec().action_space.dim();
    (0..dim).map(|i| 0.05 * (i as f64 + 1.0)).collect()
}

#[test]
fn step_into_gives_what_step_gives() {
    for ((name, mut by_step), (_, mut by_buffer)) in every_task(3).into_iter().zip(every_task(3)) {
        let action = action_of(by_step.as_ref());
        let mut observation = vec![f64::NAN; by_step.spec().observation_space.dim()];
        // What the buffer held before is replaced, not added to.
        let mut info = Info::from([("stale".into(), 1.0)]);
        for k in 0..25 {
            let step = by_step.step(&action).unwrap();
            let outcome = by_buffer
                .step_into(&action, &mut observation, &mut info)
                .unwrap();
            assert_eq!(observation, step.observation, "{name}, step {k}");
            assert_eq!(
                outcome.with_observation(observation.clone(), info.clone()),
                step,
                "{name}, step {k}"
            );
        }
    }
}

#[test]
fn a_buffer_of_the_wrong_length_is_refused_before_the_step() {
    for ((name, mut refused), (_, mut reference)) in every_task(5).into_iter().zip(every_task(5)) {
        let action = action_of(refused.as_ref());
        let dim = refused.spec().observation_space.dim();
        for wrong in [dim - 1, dim + 1] {
            let error = refused
                .step_into(&action, &mut vec![0.0; wrong], &mut Info::new())
                .unwrap_err();
            assert!(
                matches!(error, EnvError::WrongDimension { expected, got, .. }
                    if expected == dim && got == wrong),
                "{name}: {error}"
            );
        }
        // Nothing moved: the next step is the first one of the twin that was never refused.
        assert_eq!(
            refused.step(&action).unwrap(),
            reference.step(&action).unwrap(),
            "{name}"
        );
    }
}

/// A whole episode allocates nothing once the info has room for the task's values, even
/// for a task that reports more than [`INLINE`] of them (the Panda's pouring: ten). The
/// control: a fresh info at every step makes such a task allocate, so the counter would
/// see an info that spilled again.
#[test]
fn a_whole_episode_of_step_into_allocates_nothing() {
    let mut large_infos = 0;
    for (name, mut env) in every_task(7) {
        let action = action_of(env.as_ref());
        let mut observation = vec![0.0; env.spec().observation_space.dim()];
        let max_steps = env.spec().max_episode_steps;
        // The first step sizes the info.
        let mut info = Info::new();
        env.step_into(&action, &mut observation, &mut info).unwrap();
        let mut steps = 1;
        let made = count_allocations(|| {
            loop {
                let outcome = env.step_into(&action, &mut observation, &mut info).unwrap();
                steps += 1;
                if outcome.terminated || outcome.truncated {
                    break;
                }
            }
        });
        assert!(steps > 10 && steps <= max_steps, "{name}: {steps} steps");
        assert_eq!(made, 0, "{name}: {steps} steps allocated {made} times");
        if info.len() > INLINE {
            large_infos += 1;
            // The same episode again (it lasted more than ten steps).
            env.reset(Some(7), &ResetOptions::default()).unwrap();
            let fresh = count_allocations(|| {
                for _ in 0..10 {
                    env.step_into(&action, &mut observation, &mut Info::new())
                        .unwrap();
                }
            });
            assert!(
                fresh >= 10,
                "{name}: a fresh info each step allocated {fresh} times"
            );
        }
    }
    assert!(
        large_infos >= 1,
        "no task reports more than {INLINE} info values"
    );
}

/// Negative control: the counter sees the observation `Env::step` returns, once per step.
#[test]
fn the_counter_sees_the_observation_step_returns() {
    for (name, mut env) in every_task(7) {
        let action = action_of(env.as_ref());
        let made = count_allocations(|| {
            for _ in 0..10 {
                std::hint::black_box(env.step(&action).unwrap());
            }
        });
        assert!(made >= 10, "{name}: 10 steps allocated {made} times");
    }
}
