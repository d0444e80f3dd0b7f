//! `ciflow demos` → `ciflow train` → `ciflow stability`, as separate processes: the
//! dataset one command writes trains a policy in the next, whose checkpoint is globally
//! stable and, rolled out from the demonstrations' starts, reaches their targets.

mod common;

use std::path::Path;

use ciflow_engine::flow::{CouplingKind, Policy};
use ciflow_engine::math::distance;
use common::{Scratch, ciflow, refused, succeed};
use serde_json::Value;

/// Converged: within 2 mm of the target (the task's workspace is about 2 m wide).
const GOAL_TOLERANCE: f64 = 2e-3;
/// 30 s at the task's 10 ms period; the demonstrations arrive within 8 s. With the
/// guaranteed latent rate of 0.5 /s set below, the latent distance shrinks by at least
/// `e^-15` in that time whatever the training reached; a wrongly wired target misses.
const ROLLOUT_STEPS: usize = 3000;

#[test]
fn demos_train_and_stability_compose_into_a_stable_policy_that_reaches_the_targets() {
    let scratch = Scratch::new("train-cli");
    let (demos, policy) = (scratch.arg("demos"), scratch.arg("policy"));
    succeed(&[
        "demos",
        "--task",
        "obstacle-avoidance",
        "--episodes",
        "8",
        "--kwarg",
        "obstacles=1",
        "--out",
        &demos,
    ]);
    // No --latent or --goal-context-indices: the task's defaults must apply.
    succeed(&[
        "train",
        "--task",
        "obstacle-avoidance",
        "--demos",
        &demos,
        "--out",
        &policy,
        "--epochs",
        "15",
        "--min-rate",
        "0.5",
        "--layers",
        "4",
        "--hidden",
        "32,32",
        "--spline-bins",
        "6",
    ]);
    let report: Value = serde_json::from_slice(
        &succeed(&[
            "stability",
            "--checkpoint",
            &policy,
            "--task",
            "obstacle-avoidance",
            "--starts",
            "50",
            "--negative-control",
            "--negative-control-starts",
            "40",
            "--robot-loop",
            "--robot-starts",
            "10",
            "--json",
        ])
        .stdout,
    )
    .expect("JSON report");
    let observation_space = &report["observation_space"];
    assert_eq!(
        observation_space["fraction"].as_f64(),
        Some(1.0),
        "{report}"
    );
    assert_eq!(
        observation_space["converged"].as_u64(),
        Some(50),
        "{report}"
    );
    // Obstacles and target up to 10x outside the training box: still every rollout.
    let far = &report["far_contexts"];
    assert_eq!(far["fraction"].as_f64(), Some(1.0), "{report}");
    assert_eq!(far["context_scale"].as_f64(), Some(10.0), "{report}");
    assert_eq!(far["rollouts"].as_u64(), Some(50), "{report}");
    // The same flow with its latent run backwards: the check flags it.
    assert_eq!(
        report["negative_control"]["converged"].as_u64(),
        Some(0),
        "{report}"
    );
    // Through the point mass's computed-torque loop, from starts up to 100x outside.
    assert_eq!(
        report["robot_loop"]["fraction"].as_f64(),
        Some(1.0),
        "{report}"
    );
    assert_eq!(
        report["robot_loop"]["rollouts"].as_u64(),
        Some(10),
        "{report}"
    );

    let policy = Policy::load(Path::new(&policy), Some("obstacle-avoidance")).unwrap();
    // Context [o_x, o_y, g_x, g_y]: the go-to target is its tail.
    assert_eq!(policy.config().goal_context_indices, Some(vec![2, 3]));
    assert_eq!(policy.config().state_dim, 2);
    // The spline flag shapes the task's spline coupling (no --coupling needed).
    assert_eq!(
        policy.config().coupling,
        CouplingKind::Spline {
            bins: 6,
            tail_bound: 4.0
        }
    );
    let (_, episodes) = ciflow_envs::dataset::read(Path::new(&demos)).unwrap();
    assert_eq!(episodes.len(), 8);
    let mut ws = policy.workspace();
    for (i, episode) in episodes.iter().enumerate() {
        let context = &episode.contexts[0];
        let target = &context[2..];
        let mut y = episode.observations[0][..2].to_vec();
        let mut next = vec![0.0; 2];
        let start_distance = distance(&y, target);
        for _ in 0..ROLLOUT_STEPS {
            policy.mean_next(&y, context, &mut ws, &mut next).unwrap();
            std::mem::swap(&mut y, &mut next);
        }
        let end_distance = distance(&y, target);
        assert!(
            end_distance < GOAL_TOLERANCE,
            "episode {i}: {start_distance:.3} m from the target at the start, \
             {end_distance:.2e} m after {ROLLOUT_STEPS} steps"
        );
    }
}

/// `ciflow train --demos D --out P ARGS` on a one-episode limit-cycle dataset `D`: it
/// fails, writes no checkpoint, and returns what it printed on stderr.
fn refused_training(name: &str, args: &[&str]) -> String {
    let scratch = Scratch::new(name);
    let (demos, policy) = (scratch.arg("demos"), scratch.arg("policy"));
    succeed(&[
        "demos",
        "--task",
        "limit-cycle",
        "--episodes",
        "1",
        "--out",
        &demos,
    ]);
    let mut command = vec!["train", "--demos", &demos, "--out", &policy];
    command.extend_from_slice(args);
    let output = ciflow(&command);
    assert!(!output.status.success());
    assert!(!Path::new(&policy).exists(), "no checkpoint may be written");
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn train_refuses_a_dataset_of_another_task() {
    let stderr = refused_training(
        "train-cli-task",
        &["--task", "obstacle-avoidance", "--epochs", "1"],
    );
    assert!(
        stderr.contains("ciflow/LimitCycle-v0") && stderr.contains("obstacle-avoidance"),
        "{stderr}"
    );
}

/// Spline settings for an affine coupling are refused, not silently ignored.
#[test]
fn train_refuses_spline_flags_for_an_affine_coupling() {
    let stderr = refused_training(
        "train-cli-spline",
        &[
            "--task",
            "limit-cycle",
            "--coupling",
            "affine",
            "--spline-bins",
            "12",
        ],
    );
    assert!(stderr.contains("--spline-bins"), "{stderr}");
}

/// Thread counts libtorch cannot run (`tch` panicked on 0, libtorch aborted on 100 000)
/// are refused before training.
#[test]
fn train_refuses_thread_counts_out_of_range() {
    for threads in ["0", "-1", "100000"] {
        let stderr = refused_training(
            &format!("train-cli-threads{threads}"),
            &["--task", "limit-cycle", &format!("--threads={threads}")],
        );
        assert!(
            stderr.contains(&format!(
                "threads must be between 1 and 1024, not {threads}"
            )),
            "{stderr}"
        );
    }
}

/// A context set reaching past the limit cycle's 1-D context is refused, not indexed
/// out of the context while the data is prepared.
#[test]
fn train_refuses_context_sets_outside_the_context() {
    let stderr = refused_training(
        "train-cli-context-sets",
        &["--task", "limit-cycle", "--context-sets", "0:5:3"],
    );
    assert!(stderr.contains("within the 1-D context"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Local features far too wide to allocate are refused, for any task.
#[test]
fn train_refuses_absurdly_wide_local_features() {
    let stderr = refused_training(
        "train-cli-local-features",
        &["--task", "limit-cycle", "--local-features", "100000"],
    );
    assert!(
        stderr.contains("--local-features 100000: at most 1024"),
        "{stderr}"
    );
}

/// `--arrival` is a share of the training pairs: outside [0, 1] (NaN included) it is
/// refused rather than silently treated as 0.
#[test]
fn train_refuses_an_arrival_share_outside_0_to_1() {
    for arrival in ["1.5", "-1", "NaN"] {
        let stderr = refused_training(
            &format!("train-cli-arrival{arrival}"),
            // Space-separated: a negative value is a value, not a flag.
            &["--task", "limit-cycle", "--arrival", arrival],
        );
        assert!(
            stderr.contains(&format!("it must be in [0, 1], not {arrival}")),
            "{stderr}"
        );
    }
}

#[test]
fn train_refuses_publishing_with_arguments_the_task_refuses() {
    let stderr = refused_training(
        "train-cli-publish-kwarg",
        &[
            "--task",
            "limit-cycle",
            "--publish",
            "cycle",
            "--kwarg",
            "bogus=1",
        ],
    );
    assert!(
        stderr.contains("--kwarg") && stderr.contains("this task takes none"),
        "{stderr}"
    );
}

#[test]
fn train_from_zenoh_refuses_a_timeout_that_is_not_a_duration() {
    for timeout in ["1e300", "0", "-1"] {
        let scratch = Scratch::new(&format!("train-cli-timeout{timeout}"));
        refused(
            &[
                "train",
                "--task",
                "limit-cycle",
                "--from-zenoh",
                "3",
                &format!("--episode-timeout={timeout}"),
                "--out",
                &scratch.arg("policy"),
            ],
            "give a positive number of seconds up to",
        );
    }
    // Without --from-zenoh there is no episode to wait for: refused, not unused.
    let scratch = Scratch::new("train-cli-timeout-unused");
    refused(
        &[
            "train",
            "--task",
            "limit-cycle",
            "--demos",
            &scratch.arg("demos"),
            "--episode-timeout=5",
            "--out",
            &scratch.arg("policy"),
        ],
        "--from-zenoh",
    );
}

/// `ciflow train --demos <2 limit-cycle episodes> --out <out> ARGS`, small and quick.
fn train_limit_cycle(scratch: &Scratch, out: &Path, args: &[&str]) -> std::process::Output {
    let demos = scratch.arg("demos");
    if !Path::new(&demos).exists() {
        succeed(&[
            "demos",
            "--task",
            "limit-cycle",
            "--episodes",
            "2",
            "--out",
            &demos,
        ]);
    }
    let out = out.to_string_lossy();
    let mut command = vec![
        "train",
        "--task",
        "limit-cycle",
        "--demos",
        &demos,
        "--out",
        &out,
        "--epochs",
        "1",
        "--layers",
        "1",
        "--hidden",
        "4",
    ];
    command.extend_from_slice(args);
    ciflow(&command)
}

/// An --out that is a file (or lies inside one) is refused before any training, and the
/// file is left alone.
#[test]
fn train_refuses_an_out_path_that_is_a_file_before_training() {
    let scratch = Scratch::new("train-cli-out-file");
    let file = scratch.join("file");
    std::fs::write(&file, "a user's file").unwrap();
    for out in [file.clone(), file.join("policy")] {
        let output = train_limit_cycle(&scratch, &out, &[]);
        assert!(!output.status.success());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(
            stderr.contains(&format!("{} exists and is not a directory", file.display())),
            "{stderr}"
        );
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(!stdout.contains("flow:"), "trained first: {stdout}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "a user's file");
}

/// Retraining into a checkpoint directory without --baseline removes the baseline the
/// earlier run wrote there (it belongs to another flow), and nothing else: the user's
/// files stay, in the directory and in `baseline/`.
#[test]
fn train_into_an_earlier_checkpoint_leaves_no_stale_baseline() {
    let scratch = Scratch::new("train-cli-stale-baseline");
    let policy = scratch.join("policy");
    let baseline = policy.join("baseline");
    let retrain = |args: &[&str]| {
        let output = train_limit_cycle(&scratch, &policy, args);
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    let stdout = retrain(&["--baseline"]);
    assert!(baseline.join("config.json").exists());
    // The limit cycle's recipe holds nothing out: the kept epoch's score is its fit.
    assert!(
        stdout.contains("baseline: epoch 1 kept, velocity MSE ")
            && stdout.contains(" on the fitted episodes (normalised), checkpoint "),
        "{stdout}"
    );
    // The baseline's split is the flow's (same seed and fraction): one set of fitted
    // demonstrations for the control and the model it is compared with.
    let split = |dir: &std::path::Path| std::fs::read(dir.join("training_split.json")).unwrap();
    assert_eq!(split(&baseline), split(&policy));
    std::fs::write(policy.join("notes.txt"), "kept").unwrap();
    retrain(&[]);
    assert!(!baseline.exists(), "the earlier run's baseline survived");
    assert!(policy.join("config.json").exists() && policy.join("notes.txt").exists());

    retrain(&["--baseline"]);
    std::fs::write(baseline.join("notes.txt"), "kept").unwrap();
    retrain(&[]);
    let left: Vec<_> = std::fs::read_dir(&baseline)
        .unwrap()
        .map(|entry| entry.unwrap().file_name())
        .collect();
    assert_eq!(left, ["notes.txt"], "only the user's file stays");
}

/// What `ciflow train` prints about the data it leaves out (its first stdout lines).
fn screening_line(stdout: &[u8]) -> String {
    String::from_utf8_lossy(stdout)
        .lines()
        .find(|l| l.contains("failed their task"))
        .unwrap_or_default()
        .to_owned()
}

/// Pushed pouring demonstrations: the pushed steps reach the trainer flagged and stay out
/// of the likelihood (with a settling window on request); an episode that failed is
/// dropped unless --keep-failed.
#[test]
fn train_leaves_out_pushed_steps_and_failed_episodes() {
    let scratch = Scratch::new("train-cli-screening");
    let (demos, failing, policy) = (
        scratch.arg("demos"),
        scratch.arg("failing"),
        scratch.arg("policy"),
    );
    succeed(&[
        "demos",
        "--task",
        "pouring",
        "--episodes",
        "3",
        "--option",
        "push_force=40",
        "--out",
        &demos,
    ]);
    let (spec, mut episodes) = ciflow_envs::dataset::read(Path::new(&demos)).unwrap();
    let pushed_in =
        |e: &ciflow_envs::dataset::Episode| (0..e.len()).filter(|&t| e.perturbed(t)).count();
    let pushed: usize = episodes.iter().map(pushed_in).sum();
    let steps: usize = episodes.iter().map(|e| e.len()).sum();
    assert!(pushed > 0 && pushed < steps / 10, "{pushed} of {steps}");
    let train = |dataset: &str, extra: &[&str]| {
        let mut command = vec![
            "train", "--task", "pouring", "--demos", dataset, "--out", &policy, "--epochs", "1",
            "--layers", "2", "--hidden", "16",
        ];
        command.extend_from_slice(extra);
        screening_line(&succeed(&command).stdout)
    };
    let line = train(&demos, &[]);
    assert!(
        line.contains("0 of 3 episodes failed their task;")
            && line.contains(&format!(
                "{pushed} of {steps} transitions moved by an external force; {pushed} left out"
            )),
        "{line}"
    );
    // A settling window of 0.1 s leaves out 10 more steps after each episode's push.
    let line = train(&demos, &["--push-settling", "0.1"]);
    assert!(
        line.contains(&format!(
            "(+ 10 settling steps after each); {} left out",
            pushed + 30
        )),
        "{line}"
    );
    // The first episode, marked as failed at its end, is dropped; kept on request.
    let success = episodes[0].infos.get_mut("is_success").unwrap();
    *success.last_mut().unwrap() = 0.0;
    ciflow_envs::dataset::write(Path::new(&failing), &spec, &episodes, false).unwrap();
    let rest = pushed - pushed_in(&episodes[0]);
    let line = train(&failing, &[]);
    assert!(
        line.contains("1 of 3 episodes failed their task and are dropped")
            && line.contains(&format!(
                "{rest} of {} transitions moved by an external force; {rest} left out",
                steps - episodes[0].len(),
            )),
        "{line}"
    );
    let line = train(&failing, &["--keep-failed", "--keep-perturbed"]);
    assert!(
        line.contains("1 of 3 episodes failed their task, kept")
            && line.contains(&format!(
                "{pushed} of {steps} transitions moved by an external force, kept \
                 (--keep-perturbed); 0 left out"
            )),
        "{line}"
    );
}

/// `--joint-range true` builds the task's robot's limits into the policy, which
/// `ciflow stability --robot-loop` then drives through the Panda; a task without a robot
/// refuses it.
#[test]
fn train_builds_the_robots_limits_into_the_policy_on_request() {
    let stderr = refused_training(
        "train-cli-range-refused",
        &["--task", "limit-cycle", "--joint-range", "true"],
    );
    assert!(stderr.contains("--joint-range"), "{stderr}");

    let scratch = Scratch::new("train-cli-range");
    let (demos, policy) = (scratch.arg("demos"), scratch.arg("policy"));
    succeed(&[
        "demos",
        "--task",
        "pouring",
        "--episodes",
        "2",
        "--out",
        &demos,
    ]);
    succeed(&[
        "train",
        "--task",
        "pouring",
        "--demos",
        &demos,
        "--out",
        &policy,
        "--epochs",
        "1",
        "--layers",
        "2",
        "--hidden",
        "16",
        "--joint-range",
        "true",
    ]);
    let config: Value = serde_json::from_str(
        &std::fs::read_to_string(Path::new(&policy).join("config.json")).unwrap(),
    )
    .unwrap();
    let limits = ciflow_engine::robot::panda_limits();
    let range = &config["joint_range"];
    for (key, expected) in [
        ("position_min", &limits.q_min),
        ("position_max", &limits.q_max),
        ("speed_max", &limits.qd_max),
        ("acceleration_max", &limits.qdd_max),
    ] {
        let values: Vec<f64> = serde_json::from_value(range[key].clone()).unwrap();
        assert_eq!(values, expected.as_slice(), "{key}");
    }
    let output = succeed(&[
        "stability",
        "--checkpoint",
        &policy,
        "--starts",
        "10",
        "--robot-loop",
        "--robot-starts",
        "2",
        "--robot-duration",
        "2",
        "--robot-traces",
        "1",
        "--robot-push",
        "20",
        "--json",
    ]);
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    let robot_loop = &report["robot_loop"];
    assert_eq!(robot_loop["rollouts"], 2, "{robot_loop}");
    assert!(robot_loop["steps"].as_u64().unwrap() > 0, "{robot_loop}");
    assert_eq!(robot_loop["traces"].as_array().unwrap().len(), 1);
    assert_eq!(robot_loop["push"]["force"], 20.0, "{robot_loop}");
    // A setting of a check not asked for is refused, not silently unused.
    refused(
        &[
            "stability",
            "--checkpoint",
            &policy,
            "--negative-control-starts",
            "3",
        ],
        "--negative-control",
    );
}
