"""Zero set-up (an engine embedded in the first process) and reclaiming the sessions of
a client killed mid-episode — each with real processes."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import msgpack
import zenoh

import ciflow

def child_env() -> dict:
    env = dict(os.environ)
    env.pop("CIFLOW_ENGINE", None)
    return env


CHILD = textwrap.dedent(
    """
    import sys, gymnasium as gym, ciflow
    env = gym.make("ciflow/LimitCycle-v0", **eval(sys.argv[1])).unwrapped
    env.reset(seed=0)
    for _ in range(10):
        env.step(env.expert_action())
    print(env.engine_name, env.session_id, env._session.token.hex(), flush=True)
    sys.stdin.readline()
    """
)


def spawn_child(kwargs: str, env: dict) -> tuple[subprocess.Popen, str, str, bytes]:
    process = subprocess.Popen(
        [sys.executable, "-c", CHILD, kwargs],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    line = process.stdout.readline().split()
    if len(line) != 3:
        process.kill()
        raise AssertionError(f"child failed: {process.stderr.read()}")
    engine, session, token = line
    return process, engine, session, bytes.fromhex(token)


def plain_reset(endpoint: str, engine: str, session: str, token: bytes):
    """A reset from this process on another process's session: (ok, reply)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["{endpoint}"]')
    with zenoh.open(config) as z:
        replies = list(
            z.get(
                f"ciflow/v2/engine/{engine}/client/anonymous/session/{session}/reset",
                payload=msgpack.packb({"v": 2, "token": token, "seed": 1}),
                timeout=5.0,
            )
        )
    assert len(replies) == 1
    reply = replies[0]
    if reply.ok is not None:
        return True, msgpack.unpackb(reply.ok.payload.to_bytes())
    return False, msgpack.unpackb(reply.err.payload.to_bytes())


def test_zero_setup_embeds_an_engine_that_other_processes_reach(private_default_endpoint):
    env = child_env()
    process, engine, session, token = spawn_child("{}", env)
    try:
        found = [e["name"] for e in ciflow.discover(engine=private_default_endpoint)]
        assert engine in found, "the embedded engine is announced on Zenoh"
        ok, reply = plain_reset(private_default_endpoint, engine, session, token)
        assert ok, reply
        # A second zero-setup process uses the first one's engine instead of starting one.
        second, engine2, _, _ = spawn_child("{}", env)
        assert engine2 == engine
        second.communicate("\n", timeout=30)
    finally:
        process.communicate("\n", timeout=30)


def test_killed_client_sessions_are_reclaimed(engine):
    endpoint, name = engine
    process, engine_name, session, token = spawn_child(f"{{'engine': '{endpoint}'}}", child_env())
    assert engine_name == name
    ok, reply = plain_reset(endpoint, name, session, token)
    assert ok, reply
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=10)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        ok, reply = plain_reset(endpoint, name, session, token)
        if not ok:
            break
        time.sleep(0.2)
    assert not ok and reply["code"] == "unknown_session", reply
