//! `ciflow demos` → `ciflow train` → `ciflow evaluate` as separate processes: every mode of
//! `evaluate` (episodes, the expert's episodes, pushes, context changes, log-likelihood,
//! field data) writes JSON that agrees with itself and with the dataset, and bad input
//! fails with a message.

mod common;

use common::{Scratch, ciflow, refused, small_obstacle_policy, succeed};
use serde_json::Value;

fn json(path: &str) -> Value {
    serde_json::from_slice(&std::fs::read(path).expect("JSON written")).expect("valid JSON")
}

fn rate(v: &Value) -> f64 {
    let r = v.as_f64().unwrap_or_else(|| panic!("{v} is not a number"));
    assert!((0.0..=1.0).contains(&r), "{r}");
    r
}

#[test]
fn evaluate_writes_episodes_pushes_switches_likelihoods_and_fields() {
    let scratch = Scratch::new("evaluate-cli");
    let (demos, policy) = small_obstacle_policy(&scratch);
    let kwargs = ["--kwarg", "obstacles=1"];
    // By default the policy contracts about the obstacle centre (`flow::radial`) with
    // the task's layers.
    let config = json(&format!("{policy}/config.json"));
    let contractions = &config["contractions"];
    let recipe = ciflow_envs::recipes::obstacle_avoidance("obstacle-avoidance", 4).unwrap();
    assert_eq!(contractions["centres"]["count"], 1, "{config}");
    assert_eq!(
        contractions["layers"],
        recipe.contractions.unwrap().layers,
        "{config}"
    );

    let episodes = scratch.arg("experiments/obstacles/1/eval.json");
    succeed(
        &[
            &[
                "evaluate",
                "--checkpoint",
                &policy,
                "--episodes",
                "3",
                "--trajectories",
                "2",
                "--out",
                &episodes,
            ][..],
            &kwargs,
        ]
        .concat(),
    );
    let report = json(&episodes);
    assert_eq!(report["episodes"], 3);
    assert_eq!(report["results"].as_array().unwrap().len(), 3);
    assert_eq!(report["trajectories"].as_array().unwrap().len(), 2);
    assert_eq!(report["env_id"], "ciflow/Obstacle-v0");
    let successes = report["results"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["success"] == true)
        .count();
    assert_eq!(rate(&report["success_rate"]), successes as f64 / 3.0);
    rate(&report["collision_rate"]);
    assert_eq!(report["disturbance"]["mode"], "none");

    // The demonstrations' own seeds (0..6) and two more: the training fitted 5 of the 6
    // and held 1 out (the task's 20 %), which the report counts apart from seeds 6 and 7.
    let split: Value = json(&format!("{policy}/training_split.json"));
    let held_out_seeds: Vec<u64> = split["held_out"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["seed"].as_u64().unwrap())
        .collect();
    assert_eq!(split["fitted"].as_array().unwrap().len(), 5, "{split}");
    assert_eq!(held_out_seeds.len(), 1, "{split}");
    let own = scratch.arg("eval_demos.json");
    let evaluate_seeds = |seed: &str, out: &str| {
        succeed(
            &[
                &["evaluate", "--checkpoint", &policy, "--episodes", "8"][..],
                &["--seed", seed, "--out", out],
                &kwargs,
            ]
            .concat(),
        )
    };
    let printed = String::from_utf8_lossy(&evaluate_seeds("0", &own).stdout).into_owned();
    assert!(
        printed.contains("held out of training: success"),
        "{printed}"
    );
    let own = json(&own);
    let parts = &own["training_split"];
    let results = own["results"].as_array().unwrap();
    for (part, seeds) in [
        (
            "fitted",
            (0..6)
                .filter(|s| !held_out_seeds.contains(s))
                .collect::<Vec<u64>>(),
        ),
        ("held_out", held_out_seeds.clone()),
        ("not_in_data", vec![6, 7]),
    ] {
        let members: Vec<&Value> = results
            .iter()
            .filter(|r| seeds.contains(&r["seed"].as_u64().unwrap()))
            .collect();
        assert_eq!(parts[part]["episodes"], members.len(), "{part}: {parts}");
        let successes = members.iter().filter(|r| r["success"] == true).count();
        assert_eq!(
            rate(&parts[part]["success_rate"]),
            successes as f64 / members.len() as f64,
            "{part}"
        );
    }
    // Seeds past the recording replay no demonstration: no division.
    let unseen = scratch.arg("eval_unseen.json");
    evaluate_seeds("100", &unseen);
    assert_eq!(json(&unseen)["training_split"], Value::Null);

    // The expert, the reference, in the same episodes (same seeds: same contexts).
    let expert = scratch.arg("expert.json");
    succeed(
        &[
            &[
                "evaluate",
                "--expert",
                "--task",
                "obstacle-avoidance",
                "--episodes",
                "3",
            ][..],
            &kwargs,
            &["--out", &expert],
        ]
        .concat(),
    );
    let reference = json(&expert);
    assert_eq!(reference["model"], "expert");
    for (ours, theirs) in report["results"]
        .as_array()
        .unwrap()
        .iter()
        .zip(reference["results"].as_array().unwrap())
    {
        assert_eq!(ours["context"], theirs["context"]);
    }
    let no_task = ciflow(&["evaluate", "--expert", "--episodes", "1"]);
    assert!(!no_task.status.success());
    assert!(String::from_utf8_lossy(&no_task.stderr).contains("--task"));

    let pushes = scratch.arg("push.json");
    succeed(
        &[
            &[
                "evaluate",
                "--checkpoint",
                &policy,
                "--episodes",
                "2",
                "--perturb",
                "push",
                "--push-start",
                "0.5",
                "--out",
                &pushes,
            ][..],
            &kwargs,
        ]
        .concat(),
    );
    let report = json(&pushes);
    let push = &report["push"];
    assert_eq!(push["required_displacement"], 0.05);
    for result in report["results"].as_array().unwrap() {
        let displacement = result["push"]["displacement"].as_f64().unwrap();
        assert_eq!(result["push"]["displaced"], displacement >= 0.05);
    }
    rate(&push["recovered_within_deadline_fraction"]);
    assert!(report["example"]["reference"].is_object());

    let switches = scratch.arg("context.json");
    succeed(
        &[
            &[
                "evaluate",
                "--checkpoint",
                &policy,
                "--episodes",
                "2",
                "--perturb",
                "context",
                "--out",
                &switches,
            ][..],
            &kwargs,
        ]
        .concat(),
    );
    let report = json(&switches);
    assert_eq!(
        report["disturbance"]["tail"], 2,
        "obstacle-avoidance moves the target"
    );
    for result in report["results"].as_array().unwrap() {
        assert_eq!(result["switched_context"][0], result["context"][0]);
    }

    let nll = scratch.arg("nll.json");
    succeed(&[
        "evaluate",
        "--checkpoint",
        &policy,
        "--nll",
        &demos,
        "--out",
        &nll,
    ]);
    let report = json(&nll);
    let (_, data) = ciflow_envs::dataset::read(std::path::Path::new(&demos)).unwrap();
    let transitions: usize = data.iter().map(|e| e.observations.len() - 1).sum();
    assert_eq!(report["transitions"], transitions);
    assert!(report["per_transition"].as_f64().unwrap().is_finite());

    let field = scratch.arg("field.json");
    succeed(&[
        "evaluate",
        "--checkpoint",
        &policy,
        "--field",
        &field,
        "--field-demos",
        &demos,
        "--field-resolution",
        "6",
        "--field-steps",
        "50",
    ]);
    let report = json(&field);
    assert_eq!(report["fields"].as_array().unwrap().len(), 3);
    assert_eq!(
        report["fields"][0]["velocity_x"].as_array().unwrap().len(),
        6
    );
    assert_eq!(report["demonstrations"].as_array().unwrap().len(), 6);
    // A go-to task has no curve to trace.
    assert!(report["fields"][0].get("reference").is_none());
    // A window below and left of the origin (the negative bounds parse as numbers).
    succeed(&[
        "evaluate",
        "--checkpoint",
        &policy,
        "--field",
        &field,
        "--field-demos",
        &demos,
        "--field-window",
        "-1.5,-0.5,-1,-0.25",
        "--field-resolution",
        "3",
        "--field-steps",
        "5",
    ]);
    assert_eq!(
        json(&field)["window"],
        serde_json::json!([-1.5, -0.5, -1.0, -0.25])
    );

    // Refused before any episode runs: outputs that would replace an input or cannot be
    // files, and disturbances that would never happen.
    let config_file = format!("{policy}/config.json");
    let config_before = std::fs::read(&config_file).unwrap();
    let directory = scratch.arg(".");
    let refusals = [
        (vec!["--out", config_file.as_str()], "lies inside the input"),
        (vec!["--out", directory.as_str()], "is a directory"),
        (
            vec!["--perturb", "context", "--switch-time", "nan"],
            "must be finite",
        ),
        (
            vec!["--perturb", "push", "--push-start", "1e9"],
            "after the episode's end",
        ),
        // Settings of a disturbance that is not asked for, instead of silently unused.
        (vec!["--push-start", "0.5"], "--perturb"),
        (vec!["--switch-time", "0.5"], "--perturb"),
        (vec!["--field-resolution", "5"], "--field"),
        (vec!["--field-window", "0,1,0,1"], "--field"),
        (
            vec!["--field", field.as_str(), "--trajectories", "2"],
            "cannot be used with",
        ),
        (
            vec![
                "--field",
                field.as_str(),
                "--field-contexts",
                "1e308,1e308,1e308,1e308",
            ],
            "is not finite: the context lies too far outside",
        ),
    ];
    for (extra, message) in refusals {
        refused(
            &[&["evaluate", "--checkpoint", &policy][..], &kwargs, &extra].concat(),
            message,
        );
    }
    assert_eq!(std::fs::read(&config_file).unwrap(), config_before);
    refused(
        &["stability", "--checkpoint", &policy, "--robot-push", "20"],
        "--robot-loop",
    );
    let nll_pushed = ciflow(&[
        "evaluate",
        "--checkpoint",
        &policy,
        "--nll",
        &demos,
        "--perturb",
        "push",
    ]);
    assert!(
        !nll_pushed.status.success(),
        "--perturb does not apply to --nll"
    );
    // Another task's dataset is named as such, not as a context of the wrong size.
    let cycle = scratch.arg("cycle-demos");
    succeed(&[
        "demos",
        "--task",
        "limit-cycle",
        "--episodes",
        "1",
        "--out",
        &cycle,
    ]);
    let stderr = refused(
        &["evaluate", "--checkpoint", &policy, "--nll", &cycle],
        "holds episodes of ciflow/LimitCycle-v0",
    );
    assert!(stderr.contains("acts in ciflow/Obstacle-v0"), "{stderr}");

    // A checkpoint of one obstacle cannot act among two.
    let mismatch = ciflow(&[
        "evaluate",
        "--checkpoint",
        &policy,
        "--episodes",
        "1",
        "--kwarg",
        "obstacles=2",
    ]);
    assert!(!mismatch.status.success());
    assert!(String::from_utf8_lossy(&mismatch.stderr).contains("cannot act"));
}
