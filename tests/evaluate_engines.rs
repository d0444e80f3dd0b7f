//! `ciflow evaluate --engines` and `ciflow stability --engines`: the episodes of an
//! evaluation and the rollouts of a stability check run on two engines behind a router
//! (separate processes meeting over Zenoh) and give the reports of the same work run in
//! process, pushes and the negative control included; `*` finds both engines; an engine
//! that is not there, or is gone, is named in a clear error.

mod common;

use std::time::Duration;

use common::{
    Scratch, ciflow, endpoint, line_with, refused, small_obstacle_policy, spawn_ciflow, succeed,
};
use serde_json::Value;

const PORT: u16 = 17_931;

fn json(path: &str) -> Value {
    serde_json::from_slice(&std::fs::read(path).expect("JSON written")).expect("valid JSON")
}

#[test]
fn episodes_spread_over_engines_give_the_in_process_report() {
    let scratch = Scratch::new("evaluate-engines");
    let (_, policy) = small_obstacle_policy(&scratch);

    let router = endpoint(PORT);
    let ready = Duration::from_secs(30);
    let (_router, router_lines) = spawn_ciflow(&["router", "--listen", &router]);
    line_with(&router_lines, "ready", ready);
    let mut engines = Vec::new();
    for (port, name) in [(PORT + 1, "spread-a"), (PORT + 2, "spread-b")] {
        let listen = endpoint(port);
        let (process, lines) = spawn_ciflow(&[
            "serve",
            "--name",
            name,
            "--connect",
            &router,
            "--listen",
            &listen,
        ]);
        line_with(&lines, "ready", ready);
        engines.push((process, lines));
    }

    let evaluate = |out: &str, extra: &[&str]| {
        let common = [
            "evaluate",
            "--checkpoint",
            &policy,
            "--episodes",
            "8",
            "--seed",
            "5",
            "--perturb",
            "push",
            "--push-start",
            "0.5",
            "--trajectories",
            "2",
            "--out",
            out,
        ];
        succeed(&[&common[..], extra].concat())
    };
    let (local, spread) = (scratch.arg("local.json"), scratch.arg("spread.json"));
    evaluate(&local, &[]);
    let output = evaluate(&spread, &["--engines", "*", "--connect", &router]);
    let printed = String::from_utf8_lossy(&output.stdout).to_string()
        + &String::from_utf8_lossy(&output.stderr);
    assert!(
        printed.contains("on 2 engine(s): spread-a, spread-b"),
        "`*` finds both engines: {printed}"
    );
    let (local, spread) = (json(&local), json(&spread));
    assert_eq!(local["results"].as_array().map(Vec::len), Some(8));
    assert!(
        local["results"][0]["push"]["displacement"].as_f64() > Some(0.0),
        "the episodes were pushed: {}",
        local["results"][0]
    );
    assert_eq!(local["trajectories"].as_array().map(Vec::len), Some(2));
    assert_eq!(
        spread, local,
        "the engines' report equals the in-process one"
    );

    let stability = |extra: &[&str]| {
        let common = [
            "stability",
            "--checkpoint",
            &policy,
            "--starts",
            "30",
            "--max-steps",
            "3000",
            "--negative-control",
            "--negative-control-starts",
            "10",
            "--json",
        ];
        let output = ciflow(&[&common[..], extra].concat());
        assert!(
            output.status.success(),
            "{}",
            String::from_utf8_lossy(&output.stderr)
        );
        serde_json::from_slice::<Value>(&output.stdout).expect("the report as JSON")
    };
    let local = stability(&[]);
    assert_eq!(local["observation_space"]["rollouts"], 30);
    assert_eq!(local["negative_control"]["rollouts"], 10);
    let spread = stability(&["--engines", "spread-a,spread-b", "--connect", &router]);
    assert_eq!(
        spread, local,
        "the engines' stability report equals the in-process one"
    );

    // An engine that is not there, and one that went away, are named; the work ends
    // instead of waiting.
    let fails_naming = |engines: &str, engine: &str| {
        let output = ciflow(&[
            "evaluate",
            "--checkpoint",
            &policy,
            "--episodes",
            "4",
            "--engines",
            engines,
            "--connect",
            &router,
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success());
        assert!(stderr.contains(&format!("engine `{engine}`")), "{stderr}");
    };
    fails_naming("spread-a,nowhere", "nowhere");
    // Lists that could only be misread: each is refused before any work.
    for (engines, message) in [
        ("spread-a,spread-a", "engine `spread-a` is named twice"),
        ("spread-a,", "engine name `` must be letters"),
        ("*,spread-a", "`*` (every engine) and engine names together"),
    ] {
        refused(
            &[
                "evaluate",
                "--checkpoint",
                &policy,
                "--engines",
                engines,
                "--connect",
                &router,
            ],
            message,
        );
    }
    let (mut gone, _) = engines.pop().expect("two engines");
    gone.0.kill().expect("kill an engine");
    gone.0.wait().expect("the engine exits");
    fails_naming("spread-a,spread-b", "spread-b");
}
