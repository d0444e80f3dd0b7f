"""PROTOCOL.md is enough: drive an environment with only the `eclipse-zenoh` and `msgpack`
packages (and numpy for the f64 arrays) — no ciflow import in this file."""

import secrets
import time

import msgpack
import numpy as np
import pytest
import zenoh

V = 1


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
        self.client = "plain-" + secrets.token_hex(8)
        self.token = self.session.liveliness().declare_token(f"ciflow/v1/alive/client/{self.client}")

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
    ok, tasks = plain.query("ciflow/v1/engine/*/tasks", {"v": V})
    assert ok and tasks["engine"] == name
    spec = next(t["spec"] for t in tasks["tasks"] if t["spec"]["id"] == "ciflow/LimitCycle-v0")

    base = f"ciflow/v1/engine/{name}"
    ok, made = plain.query(f"{base}/make", {"v": V, "client": plain.client, "task": "ciflow/LimitCycle-v0"})
    assert ok, made
    session, token = made["session"], made["token"]
    assert len(token) == 16
    key = f"{base}/session/{session}"

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
    ok, error = plain.query(f"{key}/step", {"v": 2, "token": token, "action": f64le([0.0] * action_dim)})
    assert not ok and error["code"] == "version_mismatch"
    ok, error = plain.query(f"{key}/step", {"v": V})
    assert not ok and error["code"] == "malformed"

    ok, closed = plain.query(f"{key}/close", {"v": V, "token": token})
    assert ok
    ok, error = plain.query(f"{key}/reset", {"v": V, "token": token})
    assert not ok and error["code"] == "unknown_session"


def test_batched_step_and_frames_over_pubsub(plain, engine):
    _, name = engine
    base = f"ciflow/v1/engine/{name}"
    n = 4
    ok, made = plain.query(f"{base}/make", {"v": V, "client": plain.client, "task": "limit-cycle", "num_envs": n})
    assert ok, made
    spec = made["spec"]
    key = f"{base}/session/{made['session']}"
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
