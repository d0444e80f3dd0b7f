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
from conftest import BINARY, ciflow_cli, free_port  # noqa: E402


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
         "--push", "joint=0:20,at=0.5,duration=0.3", "--record", str(traces), "--quiet",
         "--rrd", str(tmp_path / "run.rrd")],
        stdout=subprocess.PIPE, text=True,
    )
    assert "scheduled" in pusher.stdout.readline()
    owner.run_policy("avoid", speed=2.0, steps=120)
    pushed = record(feed)
    assert pusher.wait(timeout=60) == 0
    record_file = json.loads(traces.read_text())
    recorded = record_file["samples"]
    assert recorded, "the second process recorded the telemetry"
    assert recorded[-1]["running"] is False
    # Attached by id, the script learned what the session is from the engine (describe),
    # and its Rerun recording holds one row per sample and the push.
    assert record_file["task"] == "ciflow/Obstacle-v0"
    assert record_file["kwargs"] == {"obstacles": 1.0}
    from rerun.chunk import RrdReader

    rows, events = {}, []
    for chunk in RrdReader(str(tmp_path / "run.rrd")).store().stream().to_chunks():
        if "time" not in chunk.timeline_names:
            continue  # static: the series' line names
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        if chunk.entity_path == "/run/events":
            events.append(chunk)
    assert rows["/run/state"] == len(recorded) and rows["/run/world/point"] == len(recorded)
    assert events, "the push is an event"

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


def test_policy_operations_and_their_error_codes_from_a_plain_client(policy_engine):
    """`act`, `run` and `stop` as the protocol page states them, with its codes and limits:
    `unknown_policy`, `limit_exceeded`, `policy`, `busy`, `wrong_dimension`."""
    from test_plain_zenoh import V, Plain, f64le

    endpoint, name = policy_engine
    plain = Plain(endpoint)
    base = f"ciflow/v2/engine/{name}"
    owned = plain.owned(name)
    try:
        ok, tasks = plain.query(f"{base}/tasks", {"v": V})
        info = next(p for p in tasks["policies"] if p["name"] == "avoid")
        assert info["task"] == "ciflow/Obstacle-v0"
        dim = info["observation_dim"]
        ok, made = plain.query(f"{owned}/make", {"v": V, "instance": plain.instance, "task": info["task"],
                                                "kwargs": {"obstacles": 1}})
        assert ok, made
        key, token = f"{owned}/session/{made['session']}", made["token"]
        ok, reset = plain.query(f"{key}/reset", {"v": V, "token": token, "seed": 1})
        observation = np.frombuffer(reset["observation"], "<f8")

        ok, acted = plain.query(f"{base}/policy/avoid/act", {"v": V, "observations": f64le(observation)})
        assert ok and np.frombuffer(acted["action"], "<f8").shape == (info["action_dim"],)
        ok, error = plain.query(f"{base}/policy/nobody/act", {"v": V, "observations": f64le(observation)})
        assert not ok and error["code"] == "unknown_policy"
        ok, error = plain.query(f"{base}/policy/avoid/act", {"v": V, "observations": f64le(observation[:-1])})
        assert not ok and error["code"] == "wrong_dimension"
        ok, limits = plain.query(f"{owned}/limits", {"v": V})
        too_many = np.tile(observation, limits["limits"]["max_act_observations"] + 1)
        ok, error = plain.query(f"{base}/policy/avoid/act", {"v": V, "observations": f64le(too_many)})
        assert not ok and error["code"] == "limit_exceeded"
        far = observation.copy()
        far[:2] = 1e300
        ok, reply = plain.query(f"{base}/policy/avoid/act", {"v": V, "observations": f64le(far)})
        if ok:  # clipped to the action space
            assert np.isfinite(np.frombuffer(reply["action"], "<f8")).all()
        else:  # never a NaN action: refused instead
            assert reply["code"] == "policy", reply

        ok, started = plain.query(f"{key}/run", {"v": V, "token": token, "policy": "avoid", "speed": 0.5})
        assert ok and started["time"] == 0.0
        ok, error = plain.query(f"{key}/step", {"v": V, "token": token, "action": f64le([0.0, 0.0])})
        assert not ok and error["code"] == "busy"
        ok, stopped = plain.query(f"{key}/stop", {"v": V, "token": token})
        assert ok and stopped["time"] > 0.0
        ok, stepped = plain.query(f"{key}/step", {"v": V, "token": token, "action": f64le([0.0, 0.0])})
        assert ok, stepped
        assert dim == len(observation)
    finally:
        plain.close()


def test_a_served_policy_acts_for_a_plain_loop_without_gymnasium(policy_engine):
    endpoint, name = policy_engine
    policy = ciflow.Policy("avoid", engine=endpoint)
    assert (policy.engine, policy.task) == (name, "ciflow/Obstacle-v0")
    assert (policy.observation_dim, policy.action_dim) == (8, 2)
    observation = np.array([-0.8, 0.3, 0.1, -0.2, 0.0, -0.7, 0.8, 0.1])
    action = policy.act(observation)
    assert action.shape == (2,) and np.all(np.isfinite(action)) and np.any(action != 0.0)
    # A batch is acted row by row: the same rows give the same actions.
    batch = policy.act(np.stack([observation, observation * 0.5, observation]))
    assert batch.shape == (3, 2)
    np.testing.assert_array_equal(batch[0], action)
    np.testing.assert_array_equal(batch[2], action)
    assert not np.array_equal(batch[1], action)
    # The caller's own arrays, as Gymnasium's are: scaling one in place changes no other.
    assert action.flags.writeable and batch.flags.writeable
    action *= 0.5
    np.testing.assert_array_equal(batch[0], 2.0 * action)
    with pytest.raises(ValueError, match=r"\(8,\) or \(n, 8\)"):
        policy.act(observation[:-1])
    with pytest.raises(ciflow.EngineUnreachable, match="serves a policy named 'nobody'"):
        ciflow.Policy("nobody", engine=endpoint)


def test_the_1khz_control_loop_example_calls_a_served_policy(policy_engine):
    endpoint, _ = policy_engine
    example = Path(__file__).resolve().parent.parent / "examples" / "control_loop.py"
    result = subprocess.run(
        [sys.executable, str(example), endpoint, "avoid", "--seconds", "0.5"],
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr
    line = next(l for l in result.stdout.splitlines() if l.startswith("act over Zenoh"))
    calls = int(line.split(": ")[1].split(" calls")[0])
    missed, periods = (int(x) for x in line.split("missed ")[1].split(" deadlines")[0].split(" of "))
    # 500 periods of 1 ms: each was either answered in time or missed.
    assert periods == 500 and 0 < calls <= periods and missed <= periods


def test_the_perturb_script_runs_exactly_its_duration_and_refuses_what_would_never_act(
        policy_engine, tmp_path):
    """At speed 0 the run outpaces its telemetry: the engine itself stops it after
    --duration (before, the run went on to the episode's end). Pushes or context changes
    past the end, and engine refusals, are errors without a traceback."""
    endpoint, _name = policy_engine
    script = [sys.executable, "-m", "ciflow.perturb", "--engine", endpoint, "--task",
              "obstacle-avoidance", "--kwarg", "obstacles=1", "--seed", "3", "--policy",
              "avoid", "--quiet"]
    traces = tmp_path / "fast.json"
    done = subprocess.run(script + ["--speed", "0", "--duration", "0.5", "--record",
                                    str(traces)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    last = json.loads(traces.read_text())["samples"][-1]
    assert (last["step"], last["time"]) == (50, pytest.approx(0.5)), last

    for extra, message in (
        (["--duration", "1", "--push", "joint=0:20,at=2,duration=0.1"], "would never act"),
        (["--duration", "1", "--context-step", "at=1,value=0:0:0:0"], "would never act"),
        (["--push", "joint=0:20,at=20,duration=0.1"], "the episode's length"),
        (["--duration", "0"], "not a positive number of seconds"),
        (["--duration", "1", "--push", "link=9,force=0:1:0,at=0.1,duration=0.1"],
         "link 9 does not exist"),
    ):
        refused = subprocess.run(script + extra, capture_output=True, text=True, timeout=120)
        assert refused.returncode == 2, refused.stderr
        assert message in refused.stderr and "Traceback" not in refused.stderr, refused.stderr
