//! `ciflow` hands `train` and `lasa` to `ciflow-torch` and never loads libtorch itself:
//! an engine, a router or an evaluation starts without it.

mod common;

use std::process::Command;

use common::{Scratch, refused, succeed};

const CIFLOW_TORCH: &str = env!("CARGO_BIN_EXE_ciflow-torch");

/// The shared libraries the dynamic loader maps for `program` (what `ldd` prints: the
/// loader lists them and exits without running the program).
#[cfg(target_os = "linux")]
fn loaded_libraries(program: &str) -> String {
    let output = Command::new(program)
        .env("LD_TRACE_LOADED_OBJECTS", "1")
        .output()
        .expect("run the loader's listing");
    assert!(output.status.success(), "{output:?}");
    String::from_utf8_lossy(&output.stdout).into_owned()
}

#[test]
#[cfg(target_os = "linux")]
fn only_ciflow_torch_loads_libtorch() {
    let ciflow = loaded_libraries(env!("CARGO_BIN_EXE_ciflow"));
    assert!(ciflow.contains("libc.so"), "no listing: {ciflow}");
    assert!(
        !ciflow.contains("libtorch"),
        "ciflow loads libtorch:\n{ciflow}"
    );
    // The same listing finds libtorch where it is.
    let torch = loaded_libraries(CIFLOW_TORCH);
    assert!(torch.contains("libtorch_cpu"), "{torch}");
}

#[test]
fn train_and_lasa_take_their_options_through_ciflow() {
    let stdout = |args: &[&str]| String::from_utf8_lossy(&succeed(args).stdout).into_owned();
    let train = stdout(&["train", "--help"]);
    assert!(
        train.contains("Usage: ciflow train") && train.contains("--demos"),
        "{train}"
    );
    let lasa = stdout(&["lasa", "--help"]);
    assert!(lasa.contains("--ablation"), "{lasa}");
    // Its errors and exit status are the caller's.
    refused(&["train", "--out", "x"], "--task <TASK>");
    refused(&["lasa", "--no-such-option"], "--no-such-option");
    // `help <command>` says the same, and clap still answers it for the other commands.
    assert_eq!(stdout(&["help", "train"]), train);
    assert_eq!(stdout(&["help", "lasa"]), lasa);
    let serve = stdout(&["help", "serve"]);
    assert!(serve.contains("Usage: ciflow serve"), "{serve}");
}

#[test]
fn ciflow_without_ciflow_torch_says_what_is_missing() {
    let scratch = Scratch::new("lone-ciflow");
    let lone = scratch.join("ciflow");
    std::fs::copy(env!("CARGO_BIN_EXE_ciflow"), &lone).unwrap();
    let output = Command::new(&lone)
        .args(["train", "--help"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success() && stderr.contains("ciflow-torch not found"),
        "{stderr}"
    );
    // Every other command runs without it.
    let output = Command::new(&lone)
        .args(["robot", "--help"])
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
}
