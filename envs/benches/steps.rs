//! Environment steps per second, single environment, default physics substeps (1 ms
//! physics, 10 ms control), with the expert choosing the actions. Reported per task as
//! criterion throughput (elements = env steps).

use ciflow_envs::{Env, ResetOptions, tasks};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

const STEPS: u64 = 100;

/// Steps with a fixed action (physics only) and with the expert (physics + expert).
fn steps(c: &mut Criterion) {
    let mut group = c.benchmark_group("env_steps");
    group.throughput(Throughput::Elements(STEPS));
    group.sample_size(20);
    for task in tasks() {
        let mut env = (task.make)();
        let zero = vec![0.0; env.spec().action_space.dim()];
        let reset = |env: &mut Box<dyn Env>| {
            env.reset(Some(0), &ResetOptions::default()).unwrap();
        };
        reset(&mut env);
        group.bench_function(format!("{}/zero_action", task.name), |b| {
            b.iter(|| {
                for _ in 0..STEPS {
                    let step = env.step(&zero).unwrap();
                    if step.terminated || step.truncated {
                        reset(&mut env);
                    }
                }
            })
        });
        reset(&mut env);
        group.bench_function(format!("{}/expert", task.name), |b| {
            b.iter(|| {
                for _ in 0..STEPS {
                    let action = env.expert_action().unwrap();
                    let step = env.step(&action).unwrap();
                    if step.terminated || step.truncated {
                        reset(&mut env);
                    }
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, steps);
criterion_main!(benches);
