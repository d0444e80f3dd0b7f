"""deploy/secure/README.md followed as written, with real processes: certificates from the
script, ``ciflow router`` enforcing roles, ``ciflow serve`` as a named engine, and a Python
client that joins with ``CIFLOW_ZENOH_CONFIG`` and ``CIFLOW_IDENTITY``. A client that
claims another identity than its certificate's gets nothing; one without a certificate
cannot join. (The attacks themselves are tried in bridge/tests/access_control.rs.)"""

import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ciflow

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, ROOT, free_port, start_process  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs openssl")


def start(args: list[str], ready: str) -> subprocess.Popen:
    """``ciflow ARGS``; returns once it printed ``ready``."""
    return start_process([str(BINARY), *args], ready)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    """(directory of certificates and configurations, engine name) of a running router
    and engine, set up as the README says."""
    secure = tmp_path_factory.mktemp("secure")
    port = free_port()
    subprocess.run(
        ["bash", str(ROOT / "deploy/secure/make-certs.sh"), str(secure), "engine-1", "alice", "bob"],
        check=True,
        env={"PATH": "/usr/bin:/bin", "ROUTER_ENDPOINT": f"quic/localhost:{port}",
             "ROUTER_LISTEN": f"quic/127.0.0.1:{port}"},
    )
    router = start(
        ["router", "--config", str(secure / "router.json5"), "--engine", "engine-1",
         "--client", "alice", "--client", "bob"],
        "access control on",
    )
    engine = start(["serve", "--config", str(secure / "engine-1.json5"), "--name", "engine-1"], "ready")
    yield secure, "engine-1"
    for process in (engine, router):
        process.terminate()
        process.wait(timeout=10)


def test_a_client_joins_with_its_certificate_and_identity_and_steps(deployment, monkeypatch):
    secure, engine = deployment
    monkeypatch.setenv("CIFLOW_ZENOH_CONFIG", str(secure / "alice.json5"))
    monkeypatch.setenv("CIFLOW_IDENTITY", "alice")
    env = gym.make("ciflow/LimitCycle-v0", engine=engine)
    observation, _ = env.reset(seed=0)
    for _ in range(20):
        observation, _, _, _, _ = env.step(env.unwrapped.expert_action())
    assert np.all(np.isfinite(observation))
    env.close()


def test_an_identity_other_than_the_certificates_gets_nothing(deployment, monkeypatch):
    secure, engine = deployment
    # bob's name with alice's certificate: the router drops every request under bob's keys.
    monkeypatch.setenv("CIFLOW_ZENOH_CONFIG", str(secure / "alice.json5"))
    monkeypatch.setenv("CIFLOW_IDENTITY", "bob")
    with pytest.raises(ciflow.EngineUnreachable):
        gym.make("ciflow/LimitCycle-v0", engine=engine)


def test_without_a_certificate_nobody_joins(deployment, monkeypatch, tmp_path):
    secure, engine = deployment
    text = (secure / "alice.json5").read_text()
    lines = [line for line in text.splitlines() if "connect_certificate" not in line
             and "connect_private_key" not in line]
    (tmp_path / "anonymous.json5").write_text("\n".join(lines))
    monkeypatch.setenv("CIFLOW_ZENOH_CONFIG", str(tmp_path / "anonymous.json5"))
    monkeypatch.delenv("CIFLOW_IDENTITY", raising=False)
    with pytest.raises(ciflow.EngineUnreachable):
        gym.make("ciflow/LimitCycle-v0", engine=engine)
