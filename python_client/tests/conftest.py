"""Shared fixtures: an engine in a separate process on a private loopback port, and where
the command-line binary is."""

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: The `ciflow` command line `cargo build --release` makes.
BINARY = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target")) / "release" / "ciflow"


def ciflow_cli(*args):
    """Runs the `ciflow` binary with `args` (paths and numbers as text); fails on an error."""
    subprocess.run([str(BINARY), *map(str, args)], check=True, capture_output=True, timeout=1200)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_process(argv: list[str], ready: str = "ready") -> subprocess.Popen:
    """Starts ``argv``; returns once a line of its output contains ``ready``."""
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if ready in line:
            return process
        if process.poll() is not None:
            break
    process.kill()
    raise RuntimeError(f"`{' '.join(map(str, argv))}` did not start: {process.stdout.read()}")


def start_engine(endpoint: str, name: str) -> subprocess.Popen:
    """``python -m ciflow serve`` on ``endpoint``; returns once it announced itself."""
    return start_process([sys.executable, "-m", "ciflow", "serve", "--listen", endpoint, "--name", name])


@pytest.fixture(scope="session")
def engine():
    """(endpoint, name) of an engine running in its own process."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    name = "pytest-engine"
    process = start_engine(endpoint, name)
    yield endpoint, name
    process.terminate()
    process.wait(timeout=10)


@pytest.fixture
def private_default_endpoint(monkeypatch):
    """Points the zero-configuration default at a fresh port, for this test and its
    subprocesses."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    monkeypatch.setenv("CIFLOW_DEFAULT_ENDPOINT", endpoint)
    return endpoint
