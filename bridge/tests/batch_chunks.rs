//! A batch spanning several of the engine's parallel chunks answers, row for row, what the
//! same environments answer one at a time.

mod common;

use std::collections::BTreeMap;

use common::*;

#[test]
fn a_batch_of_many_chunks_matches_single_environments() {
    let engine = start_engine(27419);
    let client = connect(27419);
    let task = "ciflow/LimitCycle-v0";
    let n = 1300;
    let batch = client
        .make(engine.name(), task, n, &BTreeMap::new())
        .unwrap();
    let spec = batch.spec().clone();
    let (obs_dim, act_dim) = (spec.observation_space.dim(), spec.action_space.dim());
    batch.reset_batch(Some(40), None).unwrap();
    let action_of = |env: usize, step: usize| -> Vec<f64> {
        (0..act_dim)
            .map(|k| ((env * 7 + step * 3 + k) % 11) as f64 * 0.1 - 0.5)
            .collect()
    };
    let singles: Vec<(usize, ciflow_bridge::RemoteEnv)> = [0, 511, 512, 1024, 1299]
        .into_iter()
        .map(|i| {
            let env = client
                .make(engine.name(), task, 1, &BTreeMap::new())
                .unwrap();
            env.reset(Some(40 + i as u64), None).unwrap();
            (i, env)
        })
        .collect();
    for step in 0..3 {
        let actions: Vec<f64> = (0..n as usize).flat_map(|i| action_of(i, step)).collect();
        let out = batch.step_batch(&actions).unwrap();
        assert_eq!(out.observations.len(), n as usize * obs_dim);
        for (i, env) in &singles {
            let one = env.step(&action_of(*i, step)).unwrap();
            assert_eq!(
                &out.observations[i * obs_dim..(i + 1) * obs_dim],
                one.observation.as_slice(),
                "env {i}, step {step}"
            );
            assert_eq!(out.rewards[*i], one.reward, "env {i}");
            assert_eq!(out.terminated[*i], one.terminated, "env {i}");
            for (key, value) in &one.info {
                assert_eq!(out.info[key.as_ref()][*i], *value, "env {i} info {key}");
            }
        }
        for column in out.info.values() {
            assert_eq!(column.len(), n as usize);
        }
    }
}
