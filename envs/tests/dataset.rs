//! The dataset format: round trips, atomic writes and typed errors.

use std::path::PathBuf;

use ciflow_envs::ResetOptions;
use ciflow_envs::dataset::{self, Credits, DatasetError, DatasetFormat, DatasetWriter};
use ciflow_envs::rollout::{
    Recording, RecordingError, expert_dataset_spec, expert_episode, record_expert_dataset,
};
use ciflow_envs::tasks::obstacle_avoidance;

fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ciflow-envs-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `episodes` expert episodes of obstacle avoidance with 2 obstacles (not the default 3).
fn two_obstacles(episodes: u64, seed: u64, credits: Credits) -> Recording {
    Recording {
        task: "obstacle-avoidance".into(),
        kwargs: [("obstacles".to_string(), 2.0.into())].into(),
        options: Default::default(),
        episodes,
        seed,
        dataset_id: None,
        credits,
        format: DatasetFormat::Minari,
    }
}

/// One expert episode of [`two_obstacles`] recorded at `out`.
fn record_one_episode(out: &std::path::Path) {
    record_expert_dataset(&two_obstacles(1, 0, Credits::default()), out, false, |_| {}).unwrap();
}

#[test]
fn recorded_expert_episodes_read_back_identically() {
    let dir = scratch_dir("round-trip");
    let out = dir.join("ciflow").join("obstacles-expert-v0");
    let credits = Credits {
        author: vec!["A. Person".into(), "B. Person".into()],
        author_email: vec!["a@example.org".into()],
        code_permalink: Some("https://example.org/ciflow/tree/abc".into()),
        description: None,
    };
    let recording = two_obstacles(4, 11, credits);
    let mut recorded = vec![];
    let spec =
        record_expert_dataset(&recording, &out, false, |e| recorded.push(e.clone())).unwrap();
    let (read_spec, episodes) = dataset::read(&out).unwrap();
    assert_eq!(read_spec, spec);
    assert_eq!(spec.dataset_id, "ciflow/obstacle-avoidance-expert-v0");
    assert_eq!(
        spec.env_kwargs,
        [("obstacles".to_string(), 2.0.into())].into()
    );
    assert_eq!(spec.credits.author, ["A. Person", "B. Person"]);
    let description = spec.credits.description.as_deref().unwrap();
    assert!(
        description.contains("ciflow/Obstacle-v0 (obstacles=2)"),
        "{description}"
    );
    assert_eq!(episodes, recorded);
    assert_eq!(
        episodes.iter().map(|e| e.seed).collect::<Vec<_>>(),
        [11, 12, 13, 14].map(Some)
    );
    // The same seeds replay the same episodes.
    let mut env = obstacle_avoidance::make(2).unwrap();
    let replay = expert_episode(&mut env, Some(13), &ResetOptions::default()).unwrap();
    assert_eq!(replay, episodes[2]);
    // An existing dataset is not overwritten unless asked.
    assert!(matches!(
        record_expert_dataset(&recording, &out, false, |_| {}),
        Err(ciflow_envs::rollout::RecordingError::Dataset(
            DatasetError::AlreadyExists(_)
        ))
    ));
    std::fs::remove_dir_all(dir).unwrap();
}

/// Overwriting replaces a dataset or an empty directory, never anything else: a directory
/// of other files and a regular file are refused and left as they were, in both formats'
/// recorders.
#[test]
fn overwrite_replaces_only_a_dataset() {
    let dir = scratch_dir("overwrite");
    let (dataset, empty, notes, file) = (
        dir.join("dataset"),
        dir.join("empty"),
        dir.join("notes"),
        dir.join("file.txt"),
    );
    let recording = two_obstacles(1, 0, Credits::default());
    record_expert_dataset(&recording, &dataset, false, |_| {}).unwrap();
    std::fs::create_dir(&empty).unwrap();
    std::fs::create_dir_all(notes.join("sub")).unwrap();
    std::fs::write(notes.join("precious.txt"), "keep me").unwrap();
    std::fs::write(&file, "keep me too").unwrap();

    for target in [&dataset, &empty] {
        dataset::check_replaceable(target, true).unwrap();
        record_expert_dataset(&recording, target, true, |_| {}).unwrap();
        assert_eq!(dataset::read(target).unwrap().1.len(), 1);
    }
    for target in [&notes, &file] {
        let refused = dataset::check_replaceable(target, true).unwrap_err();
        assert!(matches!(refused, DatasetError::NotADataset(_)), "{refused}");
        for format in [DatasetFormat::Minari, DatasetFormat::Lerobot] {
            let recording = Recording {
                format,
                ..recording.clone()
            };
            assert!(record_expert_dataset(&recording, target, true, |_| {}).is_err());
        }
        let refused = DatasetWriter::create(target, dataset::read(&dataset).unwrap().0, true);
        assert!(matches!(refused, Err(DatasetError::NotADataset(_))));
    }
    assert_eq!(
        std::fs::read_to_string(notes.join("precious.txt")).unwrap(),
        "keep me"
    );
    assert!(notes.join("sub").is_dir());
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me too");
    let mut left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|entry| entry.unwrap().file_name().into_string().unwrap())
        .collect();
    left.sort();
    assert_eq!(
        left,
        ["dataset", "empty", "file.txt", "notes"],
        "no stale copies"
    );

    // A reset option that overrides a construction argument would mislabel the data.
    let conflicting = Recording {
        options: [("obstacles".to_string(), 3.0)].into(),
        ..recording.clone()
    };
    let refused = record_expert_dataset(&conflicting, &dir.join("mislabelled"), false, |_| {});
    assert!(
        matches!(&refused, Err(RecordingError::Conflict { key, .. }) if key == "obstacles"),
        "{refused:?}"
    );
    let agreeing = Recording {
        options: [("obstacles".to_string(), 2.0)].into(),
        ..recording.clone()
    };
    record_expert_dataset(&agreeing, &dir.join("agreeing"), false, |_| {}).unwrap();

    // No episodes, or seeds that would wrap around to 0: refused, nothing written.
    for (episodes, seed) in [(0, 0), (3, u64::MAX - 1)] {
        let recording = Recording {
            episodes,
            seed,
            ..recording.clone()
        };
        let refused = record_expert_dataset(&recording, &dir.join("seeds"), false, |_| {});
        assert!(
            matches!(refused, Err(RecordingError::Seeds { .. })),
            "{refused:?}"
        );
    }
    assert!(!dir.join("seeds").exists());
    let last = Recording {
        episodes: 2,
        seed: u64::MAX - 1,
        ..recording.clone()
    };
    record_expert_dataset(&last, &dir.join("last-seeds"), false, |_| {}).unwrap();
    std::fs::remove_dir_all(dir).unwrap();
}

/// Minari's `recover_environment()` calls `gymnasium.make(EnvSpec.from_json(env_spec))`:
/// the spec must name ciflow's entry points and carry the construction arguments.
#[test]
fn the_metadata_carry_the_environment_as_gymnasium_serializes_its_spec() {
    let dir = scratch_dir("env-spec");
    let out = dir.join("obstacles-v0");
    record_one_episode(&out);
    let text = std::fs::read_to_string(out.join("data/metadata.json")).unwrap();
    let metadata: serde_json::Value = serde_json::from_str(&text).unwrap();
    let env_spec: serde_json::Value =
        serde_json::from_str(metadata["env_spec"].as_str().unwrap()).unwrap();
    assert_eq!(
        env_spec,
        serde_json::json!({
            "id": "ciflow/Obstacle-v0",
            "entry_point": dataset::GYMNASIUM_ENTRY_POINT,
            "reward_threshold": null,
            "nondeterministic": false,
            "max_episode_steps": null,
            "order_enforce": true,
            "disable_env_checker": false,
            "kwargs": {"task": "ciflow/Obstacle-v0", "obstacles": 2},
            "additional_wrappers": [],
            "vector_entry_point": dataset::GYMNASIUM_VECTOR_ENTRY_POINT,
        })
    );
    assert_eq!(
        metadata["requirements"],
        serde_json::json!([format!("ciflow=={}", env!("CARGO_PKG_VERSION"))])
    );
    assert_eq!(metadata["author"], serde_json::json!(["ciflow"]));
    // Unset contact fields are left out, as Minari leaves them out, not written empty.
    assert!(metadata.get("author_email").is_none());
    assert!(metadata.get("code_permalink").is_none());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn an_unfinished_writer_leaves_no_dataset_behind() {
    let dir = scratch_dir("atomic");
    let out = dir.join("partial-v0");
    let mut env = obstacle_avoidance::make(1).unwrap();
    let spec = expert_dataset_spec(&env, &Default::default(), "ciflow/partial-v0");
    let episode = expert_episode(&mut env, Some(0), &ResetOptions::default()).unwrap();
    {
        let mut writer = DatasetWriter::create(&out, spec.clone(), false).unwrap();
        writer.append(&episode).unwrap();
        assert!(!out.exists(), "nothing appears at the target before finish");
    }
    assert!(!out.exists());
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        0,
        "the partial data is removed"
    );
    assert!(matches!(dataset::read(&out), Err(DatasetError::Io { .. })));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn malformed_episodes_are_refused() {
    let dir = scratch_dir("malformed");
    let env = obstacle_avoidance::make(1).unwrap();
    let spec = expert_dataset_spec(&env, &Default::default(), "ciflow/bad-v0");
    let mut writer = DatasetWriter::create(&dir.join("bad-v0"), spec, false).unwrap();
    let mut episode = ciflow_envs::dataset::Episode {
        observations: vec![vec![0.0; 8]; 2],
        actions: vec![vec![0.0; 2]],
        rewards: vec![0.0],
        terminations: vec![false],
        truncations: vec![true],
        contexts: vec![vec![0.0; 4]; 2],
        ..Default::default()
    };
    assert!(writer.append(&episode).is_ok());
    episode.actions[0] = vec![f64::NAN, 0.0];
    assert!(matches!(
        writer.append(&episode),
        Err(DatasetError::InvalidEpisode { .. })
    ));
    episode.actions[0] = vec![0.0; 3];
    assert!(matches!(
        writer.append(&episode),
        Err(DatasetError::InvalidEpisode { .. })
    ));
    episode.actions.clear();
    assert!(matches!(
        writer.append(&episode),
        Err(DatasetError::InvalidEpisode { .. })
    ));
    drop(writer);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A LeRobot dataset given where this layout is read is named as one, with the way to
/// read it, instead of a missing `data/metadata.json`.
#[test]
fn a_lerobot_dataset_is_recognised_as_one() {
    let dir = scratch_dir("lerobot-read");
    std::fs::create_dir_all(dir.join("meta")).unwrap();
    std::fs::write(dir.join("meta").join("info.json"), "{}").unwrap();
    let error = dataset::read(&dir).unwrap_err().to_string();
    assert!(
        error.contains("LeRobot dataset") && error.contains("--state FIELD"),
        "{error}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// An episode whose Arrow file was never written (0 bytes) is named as such.
#[test]
fn an_empty_episode_file_is_named() {
    let dir = scratch_dir("empty-episode");
    let out = dir.join("set");
    record_one_episode(&out);
    std::fs::write(out.join("data").join("0").join("part-0.arrow"), b"").unwrap();
    let error = dataset::read(&out).unwrap_err().to_string();
    assert!(error.contains("the episode file is empty"), "{error}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// Ids Minari 0.5 opens and ids it refuses (`parse_dataset_id`); the Python tests check
/// the same refusals against Minari itself (`test_record.py`).
#[test]
fn dataset_ids_minari_cannot_open_are_refused_before_recording() {
    for id in [
        "ciflow/limit-cycle-expert-v0",
        "x-v0",
        "a/b/c-v12",
        "ab/x--v1",
        "é_1-v3",
    ] {
        dataset::check_dataset_id(id).unwrap_or_else(|e| panic!("{id}: {e}"));
    }
    for id in [
        "",
        "foo",
        "foo-v",
        "foo-vx",
        "-v1",
        "a/x-v0",
        "/ab/x-v1",
        "ab/-v1",
        "ab//-v1",
        "ns/x y-v1",
        "x-v1.2",
    ] {
        let refused = dataset::check_dataset_id(id).unwrap_err();
        assert!(
            matches!(refused, DatasetError::InvalidId(_)),
            "{id}: {refused}"
        );
    }
    let dir = scratch_dir("dataset-id");
    let out = dir.join("demos");
    let recording = Recording {
        dataset_id: Some("limit cycle".into()),
        ..two_obstacles(1, 0, Credits::default())
    };
    let refused = record_expert_dataset(&recording, &out, false, |_| {}).unwrap_err();
    assert!(refused.to_string().contains("`limit cycle`"), "{refused}");
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        0,
        "nothing written"
    );
    std::fs::remove_dir_all(dir).unwrap();
}
