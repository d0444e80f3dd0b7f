//! The runnable examples (`bridge/examples`, `envs/examples`) run and do what their docs
//! say: `cargo test` builds them, and this test runs the quick ones as separate
//! processes — stepping a served task, pushing a session, acting from a checkpoint
//! without Zenoh, publishing a checkpoint that a running `ciflow serve` hot-loads, the
//! 1 kHz control loops over Zenoh and in process, and batched stepping spread over two
//! engines behind a router.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use ciflow_engine::flow::checkpoint;
use ciflow_engine::flow::{CheckpointConfig, CouplingKind, FlowConfig, LatentKind, Weights};
use common::{Scratch, endpoint, line_with, serve, spawn_ciflow};
use rand::SeedableRng;

/// The example binary `name`, which `cargo test` builds into `<target>/<profile>/examples`.
fn example(name: &str) -> PathBuf {
    let test = std::env::current_exe().expect("the test binary's path");
    let profile = test
        .parent()
        .and_then(Path::parent)
        .expect("tests run from <target>/<profile>/deps");
    let path = profile.join("examples").join(name);
    assert!(
        path.exists(),
        "{} is missing: `cargo test` builds the examples (a filtered `--test` run does not)",
        path.display()
    );
    path
}

/// Runs example `name` with `args`; asserts success and returns its standard output.
fn run(name: &str, args: &[&str]) -> String {
    let output = Command::new(example(name))
        .args(args)
        .output()
        .expect("run the example");
    assert!(
        output.status.success(),
        "example {name} {args:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8(output.stdout).expect("UTF-8 output")
}

/// A random limit-cycle flow checkpoint in `dir`: its task builds with default arguments.
fn limit_cycle_checkpoint(dir: &Path) {
    let config = FlowConfig::new(
        "limit-cycle",
        2,
        1,
        LatentKind::LimitCycle,
        CouplingKind::AFFINE,
        2,
        vec![8],
    );
    let weights = Weights::random(
        &config.parameter_shapes(),
        0.1,
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(3),
    );
    checkpoint::write(dir, &CheckpointConfig::Flow(config), &weights).unwrap();
}

#[test]
fn serve_and_step_steps_a_served_task_with_its_expert() {
    let out = run("serve_and_step", &[&endpoint(27441)]);
    assert!(out.contains("after 200 expert steps"), "{out}");
}

#[test]
fn batched_steps_spreads_its_environments_over_the_engines_listed() {
    let router = endpoint(27561);
    let (_router, lines) = spawn_ciflow(&["router", "--listen", &router]);
    line_with(&lines, "ready", Duration::from_secs(30));
    let _engines = [(27562, "steps-a"), (27563, "steps-b")]
        .map(|(port, name)| serve(port, name, &["--connect", &router]));
    let args = [
        &router,
        "ciflow/LimitCycle-v0",
        "5",
        "0.2",
        "steps-a,steps-b",
    ];
    let report: serde_json::Value =
        serde_json::from_str(run("batched_steps", &args).trim()).expect("one JSON line");
    assert_eq!(report["engines"], serde_json::json!(["steps-a", "steps-b"]));
    assert_eq!(report["num_envs"], 5);
    assert!(
        report["env_steps_per_s"].as_f64().is_some_and(|r| r > 0.0),
        "{report}"
    );
}

#[test]
fn perturb_session_moves_the_pushed_environment_off_its_twin() {
    let out = run("perturb_session", &[&endpoint(27442)]);
    let largest: f64 = out
        .lines()
        .find_map(|l| l.strip_prefix("largest distance "))
        .and_then(|rest| rest.trim_end_matches(" m").parse().ok())
        .unwrap_or_else(|| panic!("no largest distance in {out}"));
    // A 3 N push for 0.2 s on the 1 kg point mass moves it by centimetres; unpushed
    // twins stay together to the bit.
    assert!(largest > 0.005, "{out}");
    let before_push = out.lines().find(|l| l.starts_with("step   0:")).unwrap();
    assert!(before_push.ends_with("0.0000 m"), "{out}");
}

#[test]
fn act_from_checkpoint_runs_an_episode_of_the_checkpoints_task() {
    let scratch = Scratch::new("example-act");
    limit_cycle_checkpoint(&scratch.join("policy"));
    let out = run("act_from_checkpoint", &[&scratch.arg("policy")]);
    assert!(out.contains("ciflow/LimitCycle-v0"), "{out}");
    assert!(out.contains(" steps, return "), "{out}");
}

#[test]
fn publish_checkpoint_makes_a_running_engine_serve_the_policy() {
    let scratch = Scratch::new("example-publish");
    limit_cycle_checkpoint(&scratch.join("policy"));
    let port = 27443;
    let _engine = serve(port, "examples", &[]);
    let out = run(
        "publish_checkpoint",
        &[&endpoint(port), &scratch.arg("policy"), "published"],
    );
    assert!(
        out.contains("serves policy `published` for ciflow/LimitCycle-v0"),
        "{out}"
    );
}

/// `(calls, missed, periods)` of a control-loop report line starting with `prefix`.
fn loop_report(out: &str, prefix: &str) -> (usize, usize, usize) {
    let line = out
        .lines()
        .find(|l| l.starts_with(prefix))
        .unwrap_or_else(|| panic!("no `{prefix}` line in {out}"));
    let number = |after: &str, before: &str| -> usize {
        let rest = &line[line.find(after).unwrap() + after.len()..];
        rest[..rest.find(before).unwrap()].trim().parse().unwrap()
    };
    (
        number(": ", " calls"),
        number("missed ", " of "),
        number(" of ", " deadlines"),
    )
}

#[test]
fn control_loops_call_a_policy_once_per_millisecond_over_zenoh_and_in_process() {
    let scratch = Scratch::new("example-control-loop");
    limit_cycle_checkpoint(&scratch.join("policy"));
    let port = 27444;
    let policy = format!("cycle={}", scratch.arg("policy"));
    let _engine = serve(port, "loop", &["--policy", &policy]);
    let out = run(
        "control_loop",
        &[&endpoint(port), "loop", "cycle", "--seconds", "0.3"],
    );
    for prefix in ["raw Zenoh query", "act over Zenoh"] {
        let (calls, missed, periods) = loop_report(&out, prefix);
        assert_eq!(periods, 300, "{out}");
        // Every period is answered in time, or missed (late answers skip periods).
        assert!(calls > 0 && calls <= periods && missed <= periods, "{out}");
    }
    assert!(out.contains("act / raw: median"), "{out}");
    let out = run(
        "control_loop_in_process",
        &[&scratch.arg("policy"), "--seconds", "0.3"],
    );
    let (calls, _, periods) = loop_report(&out, "act in process");
    assert_eq!(periods, 300, "{out}");
    assert!(calls > 0 && calls <= periods, "{out}");
    let bad = Command::new(example("control_loop"))
        .args([&endpoint(port), "loop", "nobody", "--seconds", "0.1"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("serves no policy `nobody`"));
}
