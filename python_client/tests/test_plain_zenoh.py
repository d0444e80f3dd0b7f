"""PROTOCOL.md is enough: drive an environment with only the `eclipse-zenoh` and `msgpack`
packages (and numpy for the f64 arrays) — no ciflow import in this file."""

import secrets
import time

import msgpack
import numpy as np
import pytest
import zenoh

V = 2


def f64le(values) -> bytes:
    return np.asarray(values, dtype="<f8").tobytes()


class Plain:
    """A minimal client written from PROTOCOL.md."""

    def __init__(self, endpoint: str):
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", f'["{endpoint}"]')
        config.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(config)
        self.identity = "plain"
        self.instance = secrets.token_hex(8)
        self.token = self.session.liveliness().declare_token(
            f"ciflow/v2/alive/client/{self.identity}/{self.instance}"
        )

    def owned(self, engine: str) -> str:
        """The prefix of what this client owns on ``engine``."""
        return f"ciflow/v2/engine/{engine}/client/{self.identity}"

    def query(self, key: str, request: dict):
        """One request, one reply: (True, payload dict) or (False, error dict)."""
        replies = list(
            self.session.get(
                key,
                payload=msgpack.packb(request, use_bin_type=True),
                consolidation=zenoh.ConsolidationMode.NONE,
                timeout=10.0,
            )
        )
        assert len(replies) == 1, f"exactly one reply on {key}"
        reply = replies[0]
        if reply.ok is not None:
            return True, msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
        return False, msgpack.unpackb(reply.err.payload.to_bytes(), raw=False)

    def close(self):
        self.token.undeclare()
        self.session.close()


@pytest.fixture
def plain(engine):
    client = Plain(engine[0])
    yield client
    client.close()


def test_a_plain_zenoh_client_drives_an_environment(plain, engine):
    _, name = engine
    ok, tasks = plain.query("ciflow/v2/engine/*/tasks", {"v": V})
    assert ok and tasks["engine"] == name
    spec = next(t["spec"] for t in tasks["tasks"] if t["spec"]["id"] == "ciflow/LimitCycle-v0")

    base = f"ciflow/v2/engine/{name}"
    owned = plain.owned(name)
    ok, made = plain.query(f"{owned}/make", {"v": V, "instance": plain.instance, "task": "ciflow/LimitCycle-v0"})
    assert ok, made
    session, token = made["session"], made["token"]
    assert len(token) == 16
    key = f"{owned}/session/{session}"

    ok, reset = plain.query(f"{key}/reset", {"v": V, "token": token, "seed": 42})
    assert ok, reset
    observation = np.frombuffer(reset["observation"], "<f8")
    assert observation.shape == (len(spec["observation_space"]["low"]),)

    for step in range(1, 4):
        ok, expert = plain.query(f"{key}/expert", {"v": V, "token": token})
        assert ok, expert
        ok, out = plain.query(f"{key}/step", {"v": V, "token": token, "action": expert["action"]})
        assert ok, out
        assert out["time"] == pytest.approx(step * spec["control_dt"])
        assert isinstance(out["terminated"], bool) and isinstance(out["reward"], float)
    # A plain msgpack array of numbers is accepted too.
    action_dim = len(spec["action_space"]["low"])
    ok, out = plain.query(f"{key}/step", {"v": V, "token": token, "action": [0.0] * action_dim})
    assert ok, out

    ok, error = plain.query(f"{key}/step", {"v": V, "token": b"\0" * 16, "action": f64le([0.0] * action_dim)})
    assert not ok and error["code"] == "forbidden"
    ok, error = plain.query(f"{key}/step", {"v": V, "token": token, "action": f64le([np.nan] * action_dim)})
    assert not ok and error["code"] == "not_finite"
    ok, error = plain.query(f"{key}/step", {"v": 1, "token": token, "action": f64le([0.0] * action_dim)})
    assert not ok and error["code"] == "version_mismatch"
    ok, error = plain.query(f"{key}/step", {"v": V})
    assert not ok and error["code"] == "malformed"

    ok, closed = plain.query(f"{key}/close", {"v": V, "token": token})
    assert ok
    ok, error = plain.query(f"{key}/reset", {"v": V, "token": token})
    assert not ok and error["code"] == "unknown_session"


def test_batched_step_and_frames_over_pubsub(plain, engine):
    _, name = engine
    base = f"ciflow/v2/engine/{name}"
    owned = plain.owned(name)
    n = 4
    ok, made = plain.query(f"{owned}/make", {"v": V, "instance": plain.instance, "task": "limit-cycle", "num_envs": n})
    assert ok, made
    spec = made["spec"]
    key = f"{owned}/session/{made['session']}"
    token = made["token"]
    ok, reset = plain.query(f"{key}/reset_batch", {"v": V, "token": token, "seed": 0})
    assert ok, reset
    obs_dim = len(spec["observation_space"]["low"])
    assert np.frombuffer(reset["observations"], "<f8").shape == (n * obs_dim,)
    action_dim = len(spec["action_space"]["low"])
    ok, out = plain.query(f"{key}/step_batch", {"v": V, "token": token, "actions": f64le(np.zeros(n * action_dim))})
    assert ok, out
    assert len(out["terminated"]) == n and np.frombuffer(out["rewards"], "<f8").shape == (n,)

    frames = plain.session.declare_subscriber(f"{key}/frame")
    sample = None
    for _attempt in range(3):  # the subscription may still be on its way to the engine
        ok, rendered = plain.query(
            f"{key}/render", {"v": V, "token": token, "index": 2, "width": 32, "height": 16}
        )
        assert ok, rendered
        deadline = time.monotonic() + 2.0
        while sample is None and time.monotonic() < deadline:
            candidate = frames.try_recv()
            if candidate is None:
                time.sleep(0.01)
            elif msgpack.unpackb(candidate.attachment.to_bytes(), raw=False) == rendered["frame"]:
                sample = candidate
        if sample is not None:
            break
    assert sample is not None, "frame published"
    assert len(sample.payload.to_bytes()) == 32 * 16 * 3
    frames.undeclare()
    plain.query(f"{key}/close", {"v": V, "token": token})


def test_every_operation_error_code_and_limit_of_the_page(plain, engine):
    """The page's operations, error codes and limits, each met from a plain client.
    Not reachable from outside by design: `internal` (a caught engine bug; the Rust tests
    provoke it with a task that panics) and `simulation` (a diverging simulation). The
    policy codes (`act`, `run`, `busy`, `policy`) are met in test_policy_run.py."""
    _, name = engine
    base = f"ciflow/v2/engine/{name}"
    owned = plain.owned(name)

    def code(key, request):
        ok, reply = plain.query(key, request)
        assert not ok, f"{key} accepted {request}"
        return reply["code"]

    # ping echoes; limits are public and count per client.
    replies = list(plain.session.get(f"{base}/ping", payload=b"\x01\x02", timeout=10.0))
    assert replies[0].ok.payload.to_bytes() == b"\x01\x02"
    ok, limits = plain.query(f"{owned}/limits", {"v": V, "instance": plain.instance})
    assert ok and limits["usage"] == {"sessions": 0, "envs": 0}
    bounds = limits["limits"]
    assert bounds["max_envs_per_session"] >= 1 and bounds["max_request_bytes"] == 64 << 20

    # make: unknown task, no token, bad names, too many environments, past its deadline.
    make = {"v": V, "instance": plain.instance, "task": "limit-cycle"}
    assert code(f"{owned}/make", {**make, "task": "juggling"}) == "unknown_task"
    assert code(f"{owned}/make", {**make, "instance": "nobody-" + secrets.token_hex(4)}) == "no_liveliness"
    assert code(f"{owned}/make", {**make, "instance": ""}) == "invalid_request"
    assert code(f"{owned}/make", {**make, "num_envs": 0}) == "invalid_request"
    too_many = bounds["max_envs_per_session"] + 1
    assert code(f"{owned}/make", {**make, "num_envs": too_many}) == "limit_exceeded"
    slow = {**make, "task": "pouring", "num_envs": bounds["max_envs_per_session"], "deadline_ms": 50}
    assert code(f"{owned}/make", slow) == "deadline_exceeded"
    assert code(f"{owned}/make", {**make, "kwargs": {"no_such_argument": 1.0}}) == "invalid_option"
    ok, limits = plain.query(f"{owned}/limits", {"v": V, "instance": plain.instance})
    assert limits["usage"] == {"sessions": 0, "envs": 0}, "refusals keep nothing"

    # The decoder: maps only, tokens are bins, payloads up to 64 MiB, keys of the page.
    assert code(f"{base}/tasks", [V]) == "malformed"
    ok, made = plain.query(f"{owned}/make", {**make, "task": "obstacle-avoidance", "kwargs": {"obstacles": 1}})
    assert ok, made
    key = f"{owned}/session/{made['session']}"
    token = made["token"]
    assert code(f"{key}/step", {"v": V, "token": list(token), "action": f64le([0, 0])}) == "malformed"
    oversized = list(plain.session.get(f"{key}/step", payload=b"\x80" * ((64 << 20) + 1), timeout=30.0))
    assert msgpack.unpackb(oversized[0].err.payload.to_bytes())["code"] == "payload_too_large"
    assert code(f"{key}/fly", {"v": V, "token": token}) == "unknown_operation"
    assert code(f"{owned}/session/0000000000000000/step", {"v": V, "token": token}) == "unknown_session"

    # Before the first reset: the expert, context and perturbations need one.
    assert code(f"{key}/expert", {"v": V, "token": token}) == "needs_reset"
    ok, reset = plain.query(f"{key}/reset", {"v": V, "token": token, "seed": 3})
    assert ok, reset
    sampled = np.frombuffer(reset["observation"], "<f8")[-4:]

    # check_context: the task's own contexts are valid; one inside the box may not be.
    ok, check = plain.query(f"{key}/check_context", {"v": V, "token": token, "context": f64le(sampled)})
    assert ok and check["valid"], check
    space = made["spec"]["context_space"]
    near = [space["high"][0], 0.0, space["low"][2], 0.0]
    ok, check = plain.query(f"{key}/check_context", {"v": V, "token": token, "context": f64le(near)})
    assert ok and not check["valid"] and "safety disc" in check["reason"]
    assert code(f"{key}/context", {"v": V, "token": token, "context": f64le(near)}) == "out_of_bounds"
    assert code(f"{key}/check_context", {"v": V, "token": token, "context": f64le([0.0] * 3)}) == "wrong_dimension"
    ok, moved = plain.query(f"{key}/context", {"v": V, "token": token, "context": f64le(sampled)})
    assert ok and moved["time"] == 0.0
    # Reset options are f64s too: a bin of doubles is one number per 8 bytes.
    ok, reset = plain.query(f"{key}/reset", {"v": V, "token": token, "options": {"context": f64le(sampled)}})
    assert ok and np.allclose(np.frombuffer(reset["observation"], "<f8")[-4:], sampled)

    # perturb: typed refusals, then one accepted.
    push = {"kind": "joint_torque", "torque": [1.0, 0.0], "duration": 0.1}
    nan_start = {"v": V, "token": token, "perturbation": {**push, "start": float("nan")}}
    assert code(f"{key}/perturb", nan_start) == "not_finite"
    negative = {"v": V, "token": token, "perturbation": {**push, "duration": -1.0}}
    assert code(f"{key}/perturb", negative) == "out_of_bounds"
    wrong_link = {"kind": "link_wrench", "link": 99, "force": [1.0, 0, 0], "torque": [0, 0, 0], "duration": 0.1}
    assert code(f"{key}/perturb", {"v": V, "token": token, "perturbation": wrong_link}) == "invalid_perturbation"
    ok, accepted = plain.query(f"{key}/perturb", {"v": V, "token": token, "perturbation": push})
    assert ok, accepted

    # Sessions per client are bounded too.
    ok, limits = plain.query(f"{owned}/limits", {"v": V, "instance": plain.instance})
    assert limits["usage"] == {"sessions": 1, "envs": 1}
    opened = [made]
    for _ in range(bounds["max_sessions_per_client"] - 1):
        ok, extra = plain.query(f"{owned}/make", make)
        assert ok, extra
        opened.append(extra)
    assert code(f"{owned}/make", make) == "limit_exceeded"
    for session in opened:
        ok, _ = plain.query(f"{owned}/session/{session['session']}/close", {"v": V, "token": session["token"]})
        assert ok
    ok, limits = plain.query(f"{owned}/limits", {"v": V, "instance": plain.instance})
    assert limits["usage"] == {"sessions": 0, "envs": 0}
