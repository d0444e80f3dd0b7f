//! Shared helpers of the cross-process integration tests: running the `ciflow` binary,
//! scratch directories, child processes killed on drop, and `ciflow serve` on a private
//! loopback port.
// Each test binary compiles this module and uses only some of it.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use ciflow_bridge::protocol::ErrorCode;
use ciflow_bridge::{BridgeError, Client, NetworkOptions, Role};

/// The `ciflow` binary Cargo built for these tests.
const CIFLOW: &str = env!("CARGO_BIN_EXE_ciflow");

/// Runs `ciflow <args>` to completion and returns its status and captured output.
pub fn ciflow(args: &[&str]) -> Output {
    Command::new(CIFLOW)
        .args(args)
        .output()
        .expect("run ciflow")
}

/// Runs `ciflow <args>` and asserts that it succeeds, with its stderr in the message.
pub fn succeed(args: &[&str]) -> Output {
    let output = ciflow(args);
    assert!(
        output.status.success(),
        "ciflow {args:?} failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// Runs `ciflow <args>` and asserts that it fails with `message` in its stderr; returns
/// the stderr.
pub fn refused(args: &[&str], message: &str) -> String {
    let output = ciflow(args);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(
        !output.status.success() && stderr.contains(message),
        "ciflow {args:?} should fail with `{message}`: {stderr}"
    );
    stderr
}

/// A fresh, empty directory under the system's temporary directory, removed on drop.
/// The process id in its name keeps concurrent test runs apart.
pub struct Scratch(PathBuf);

impl Scratch {
    /// Creates `<tmp>/ciflow-<name>-<pid>`, emptying what an earlier run left there.
    pub fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("ciflow-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    /// The directory itself.
    pub fn dir(&self) -> &Path {
        &self.0
    }

    /// `name` inside the directory.
    pub fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }

    /// `name` inside the directory, as a command-line argument.
    pub fn arg(&self, name: &str) -> String {
        self.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A child process, killed when dropped so that a failing test leaves nothing running.
pub struct Process(pub Child);

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Process {
    /// Waits up to `limit` for the exit; `None` if it still runs.
    pub fn wait_for(&mut self, limit: Duration) -> Option<ExitStatus> {
        let deadline = Instant::now() + limit;
        while Instant::now() < deadline {
            if let Some(status) = self.0.try_wait().expect("try_wait") {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        None
    }

    /// Everything the process wrote to its (piped) stderr; call it once it has exited.
    pub fn stderr(&mut self) -> String {
        let mut text = String::new();
        if let Some(mut stderr) = self.0.stderr.take() {
            let _ = stderr.read_to_string(&mut text);
        }
        text
    }
}

/// Spawns `ciflow <args>` with piped stdout and stderr, and returns it with its stdout
/// lines, read on a thread so that the child never blocks on a full pipe.
pub fn spawn_ciflow(args: &[&str]) -> (Process, mpsc::Receiver<String>) {
    let mut child = Command::new(CIFLOW)
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

/// The first line containing `needle`, waiting at most `limit` for each line.
pub fn line_with(lines: &mpsc::Receiver<String>, needle: &str, limit: Duration) -> String {
    loop {
        match lines.recv_timeout(limit) {
            Ok(line) if line.contains(needle) => return line,
            Ok(_) => {}
            Err(e) => panic!("no line containing `{needle}`: {e}"),
        }
    }
}

/// The project's Python with the `ciflow` package built (`make test`, or
/// scripts/setup-python.sh and scripts/build-python.sh): `$CIFLOW_PYTHON`, else
/// `<workspace>/.venv/bin/python`. Panics, never skips, when it is missing.
pub fn python() -> PathBuf {
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

/// A small obstacle-avoidance policy (one obstacle) made by the command line in
/// `scratch`: six expert demonstrations, then two epochs of a two-layer flow with 16 × 16
/// hidden units. Returns the dataset's and the checkpoint's directories.
pub fn small_obstacle_policy(scratch: &Scratch) -> (String, String) {
    let (demos, policy) = (scratch.arg("demos"), scratch.arg("policy"));
    succeed(&[
        "demos",
        "--task",
        "obstacle-avoidance",
        "--kwarg",
        "obstacles=1",
        "--episodes",
        "6",
        "--out",
        &demos,
    ]);
    succeed(&[
        "train",
        "--task",
        "obstacle-avoidance",
        "--demos",
        &demos,
        "--out",
        &policy,
        "--epochs",
        "2",
        "--layers",
        "2",
        "--hidden",
        "16,16",
    ]);
    (demos, policy)
}

/// The Zenoh endpoint of a test engine: loopback TCP on `port`. Each test picks its own
/// port so that parallel tests never meet.
pub fn endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

/// Starts `ciflow serve --name <name>` listening on [`endpoint`]`(port)`, plus `extra`
/// arguments, and returns once it printed its ready line (its only line on stdout).
pub fn serve(port: u16, name: &str, extra: &[&str]) -> Process {
    let mut child = Command::new(CIFLOW)
        .args(["serve", "--listen", &endpoint(port), "--name", name])
        .args(extra)
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn ciflow serve");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let ready = lines.next().expect("serve printed a line").expect("utf-8");
    assert!(ready.contains("ready"), "unexpected first line: {ready}");
    Process(child)
}

/// A client session connected to the engine started by [`serve`]`(port, ..)`.
pub fn connect(port: u16) -> Client {
    Client::open(&NetworkOptions::endpoint(Role::Client, &endpoint(port))).expect("connect")
}

/// The code of a typed error the engine replied with; panics on any other error.
pub fn code(error: BridgeError) -> ErrorCode {
    match error {
        BridgeError::Remote(reply) => reply.code,
        other => panic!("expected a typed engine error, got {other}"),
    }
}
