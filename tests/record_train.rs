//! The paper's loop as separate processes that meet only over Zenoh: `ciflow serve` hosts
//! the task, `python -m ciflow.record` rolls out the expert through `gymnasium.make` and
//! publishes each episode, `ciflow train --from-zenoh N` collects them, writes them as a
//! dataset and trains a policy. Explicit loopback endpoints, no multicast.
//!
//! Needs the project's Python with the `ciflow` package built (`make test`, or
//! `scripts/setup-python.sh` and `scripts/build-python.sh`); `$CIFLOW_PYTHON` overrides
//! `<workspace>/.venv/bin/python`. Fails, never skips, when it is missing.

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use ciflow_envs::dataset;
use common::{Scratch, endpoint, line_with, python, serve, spawn_ciflow};

const PORT: u16 = 27471;
const TASK: &str = "obstacle-avoidance";

#[test]
fn recorder_episodes_reach_a_trainer_over_zenoh_and_train_a_policy() {
    let python = python();
    let scratch = Scratch::new("record-train");
    let _engine = serve(PORT, "hub", &[]);
    let endpoint = endpoint(PORT);

    // With no recorder, the trainer gives up with a clear error.
    let (mut lonely, _lines) = spawn_ciflow(&[
        "train",
        "--task",
        TASK,
        "--from-zenoh",
        "2",
        "--episode-timeout",
        "1",
        "--connect",
        &endpoint,
        "--out",
        &scratch.arg("unused"),
    ]);
    let status = lonely.wait_for(Duration::from_secs(60)).expect("gave up");
    let error = lonely.stderr();
    assert!(!status.success());
    assert!(
        error.contains("0 of 2 episodes") && error.contains("recorder must be running"),
        "{error}"
    );

    let (policy, collected, recorded) = (
        scratch.arg("policy"),
        scratch.arg("collected"),
        scratch.arg("recorded"),
    );
    let (mut trainer, trainer_lines) = spawn_ciflow(&[
        "train",
        "--task",
        TASK,
        "--from-zenoh",
        "3",
        "--epochs",
        "2",
        "--connect",
        &endpoint,
        "--demos",
        &collected,
        "--out",
        &policy,
    ]);
    let waiting = line_with(
        &trainer_lines,
        "waiting for 3 episodes",
        Duration::from_secs(60),
    );
    assert!(
        waiting.contains("ciflow/v2/episodes/obstacle-avoidance/*"),
        "{waiting}"
    );

    let record = Command::new(&python)
        .args([
            "-m",
            "ciflow.record",
            "--task",
            TASK,
            "--kwarg",
            "obstacles=1",
            "--episodes",
            "3",
            "--seed",
            "4",
            "--out",
            &recorded,
            "--engine",
            &endpoint,
            "--quiet",
        ])
        .env_remove("CIFLOW_ENGINE")
        .output()
        .expect("run the recorder");
    assert!(
        record.status.success(),
        "recorder failed: {}",
        String::from_utf8_lossy(&record.stderr)
    );
    let status = trainer
        .wait_for(Duration::from_secs(300))
        .expect("the trainer finished");
    assert!(status.success(), "trainer failed: {}", trainer.stderr());

    for file in ["config.json", "weights.safetensors"] {
        assert!(Path::new(&policy).join(file).is_file(), "checkpoint {file}");
    }
    let (spec, episodes) = dataset::read(Path::new(&collected)).expect("the collected dataset");
    let (recorded_spec, recorded_episodes) =
        dataset::read(Path::new(&recorded)).expect("the recorder's dataset");
    assert_eq!(episodes.len(), 3);
    assert_eq!(spec, recorded_spec);
    assert_eq!(
        episodes, recorded_episodes,
        "the trainer's dataset is the recorder's, episode for episode"
    );
    assert_eq!(
        episodes.iter().map(|e| e.seed).collect::<Vec<_>>(),
        [Some(4), Some(5), Some(6)]
    );
}
