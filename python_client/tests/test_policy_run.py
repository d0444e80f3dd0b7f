"""A policy driving a session in a `ciflow serve --policy` engine, perturbed from a second
process with ``python -m ciflow.perturb`` attached by session id and token."""

import json
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ciflow

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, free_port  # noqa: E402


def ciflow_cli(*args):
    subprocess.run([str(BINARY), *map(str, args)], check=True, capture_output=True, timeout=600)


@pytest.fixture(scope="module")
def policy_engine(tmp_path_factory):
    """(endpoint, name) of `ciflow serve` with a freshly trained obstacle policy `avoid`."""
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    scratch = tmp_path_factory.mktemp("policy")
    ciflow_cli("demos", "--task", "obstacle-avoidance", "--episodes", "4",
               "--kwarg", "obstacles=1", "--out", scratch / "demos")
    ciflow_cli("train", "--task", "obstacle-avoidance", "--demos", scratch / "demos",
               "--out", scratch / "avoid", "--epochs", "2", "--layers", "2", "--hidden", "16,16")
    endpoint, name = f"tcp/127.0.0.1:{free_port()}", "pytest-policy"
    process = subprocess.Popen(
        [str(BINARY), "serve", "--listen", endpoint, "--name", name, "--telemetry-hz", "2000",
         "--policy", f"avoid={scratch / 'avoid'}", "--policy-kwarg", "obstacles=1"],
        stdout=subprocess.PIPE, text=True,
    )
    assert "ready" in process.stdout.readline()
    yield endpoint, name
    process.terminate()
    process.wait(timeout=10)


def record(feed) -> list[dict]:
    """The samples of one run: from its first step to the sample that ends it."""
    samples = []
    for sample in feed:
        if not samples and not sample["running"]:
            continue  # the reset's sample
        samples.append(sample)
        if not sample["running"]:
            return samples
    raise AssertionError("the run never ended")


def test_run_policy_is_perturbed_from_a_second_process(policy_engine, tmp_path):
    endpoint, name = policy_engine
    env = gym.make("ciflow/Obstacle-v0", engine=endpoint, obstacles=1)
    owner = env.unwrapped
    feed = owner.attach().telemetry(timeout=10.0)
    time.sleep(0.3)

    env.reset(seed=3)
    owner.run_policy("avoid", speed=4.0, steps=120)
    with pytest.raises(ciflow.CiflowError, match="busy"):
        env.step(np.zeros(2))
    reference = record(feed)
    assert reference[-1]["step"] <= 120

    env.reset(seed=3)
    traces = tmp_path / "traces.json"
    pusher = subprocess.Popen(
        [sys.executable, "-m", "ciflow.perturb", "--session", owner.session_id,
         "--token", owner.token_hex, "--engine", endpoint, "--engine-name", name,
         "--push", "joint=0:20,at=0.5,duration=0.3", "--record", str(traces), "--quiet"],
        stdout=subprocess.PIPE, text=True,
    )
    assert "scheduled" in pusher.stdout.readline()
    owner.run_policy("avoid", speed=2.0, steps=120)
    pushed = record(feed)
    assert pusher.wait(timeout=60) == 0
    recorded = json.loads(traces.read_text())["samples"]
    assert recorded, "the second process recorded the telemetry"
    assert recorded[-1]["running"] is False

    # The push shows in the telemetry: the y-velocity departs from the reference run.
    by_step = {s["step"]: s for s in reference}
    departure = max(
        abs(s["state"][3] - by_step[s["step"]]["state"][3])
        for s in pushed
        if 0.55 <= s["time"] <= 0.85 and s["step"] in by_step
    )
    assert departure > 0.3, departure
    before = [s for s in pushed if s["time"] < 0.5 and s["step"] in by_step]
    assert before and all(
        np.allclose(s["state"], by_step[s["step"]]["state"]) for s in before
    ), "before the push both runs coincide"
    env.close()
