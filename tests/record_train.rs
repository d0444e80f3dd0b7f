//! The paper's loop as separate processes that meet only over Zenoh: `ciflow serve` hosts
//! the task, `python -m ciflow.record` rolls out the expert through `gymnasium.make` and
//! publishes each episode, `ciflow train --from-zenoh N` collects them, writes them as a
//! dataset and trains a policy. Explicit loopback endpoints, no multicast.
//!
//! Needs the project's Python with the `ciflow` package built (`make test`, or
//! `scripts/setup-python.sh` and `scripts/build-python.sh`); `$CIFLOW_PYTHON` overrides
//! `<workspace>/.venv/bin/python`. Fails, never skips, when it is missing.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use ciflow_envs::dataset;

const PORT: u16 = 27471;
const TASK: &str = "obstacle-avoidance";

fn python() -> PathBuf {
    let path = std::env::var_os("CIFLOW_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python"));
    assert!(
        path.exists(),
        "Python with the ciflow package not found at {}: run `make test` (or \
         scripts/setup-python.sh and scripts/build-python.sh, or set CIFLOW_PYTHON)",
        path.display()
    );
    let import = Command::new(&path)
        .args(["-c", "import ciflow.record"])
        .output()
        .expect("run python");
    assert!(
        import.status.success(),
        "{} cannot import ciflow.record (build it with scripts/build-python.sh): {}",
        path.display(),
        String::from_utf8_lossy(&import.stderr)
    );
    path
}

/// A child process killed when dropped.
struct Process(Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Process {
    /// Waits up to `limit` for the exit; `None` if it still runs.
    fn wait_for(&mut self, limit: Duration) -> Option<std::process::ExitStatus> {
        let deadline = std::time::Instant::now() + limit;
        while std::time::Instant::now() < deadline {
            if let Some(status) = self.0.try_wait().expect("try_wait") {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }
}

/// Spawns `ciflow <args>` and returns it with its stdout lines, read on a thread.
fn spawn_ciflow(args: &[&str]) -> (Process, mpsc::Receiver<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ciflow"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn ciflow");
    let stdout = child.stdout.take().unwrap();
    let (sender, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if sender.send(line).is_err() {
                break;
            }
        }
    });
    (Process(child), lines)
}

/// The first line containing `needle`, within `limit`.
fn line_with(lines: &mpsc::Receiver<String>, needle: &str, limit: Duration) -> String {
    loop {
        match lines.recv_timeout(limit) {
            Ok(line) if line.contains(needle) => return line,
            Ok(_) => {}
            Err(e) => panic!("no line containing `{needle}`: {e}"),
        }
    }
}

fn stderr_of(process: &mut Process) -> String {
    let mut text = String::new();
    if let Some(mut stderr) = process.0.stderr.take() {
        use std::io::Read;
        let _ = stderr.read_to_string(&mut text);
    }
    text
}

/// A fresh directory under the system's temporary directory, removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("ciflow-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn path(&self, name: &str) -> String {
        self.0.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[test]
fn recorder_episodes_reach_a_trainer_over_zenoh_and_train_a_policy() {
    let python = python();
    let scratch = Scratch::new("record-train");
    let endpoint = format!("tcp/127.0.0.1:{PORT}");
    let (_engine, engine_lines) = spawn_ciflow(&["serve", "--listen", &endpoint, "--name", "hub"]);
    line_with(&engine_lines, "ready", Duration::from_secs(60));

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
        &scratch.path("unused"),
    ]);
    let status = lonely.wait_for(Duration::from_secs(60)).expect("gave up");
    let error = stderr_of(&mut lonely);
    assert!(!status.success());
    assert!(
        error.contains("0 of 2 episodes") && error.contains("recorder must be running"),
        "{error}"
    );

    let (policy, collected, recorded) = (
        scratch.path("policy"),
        scratch.path("collected"),
        scratch.path("recorded"),
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
        waiting.contains("ciflow/v1/episodes/obstacle-avoidance/*"),
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
    assert!(
        status.success(),
        "trainer failed: {}",
        stderr_of(&mut trainer)
    );

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
