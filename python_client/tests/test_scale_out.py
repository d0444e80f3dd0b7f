"""One Gymnasium vector environment over several engines joined by a Zenoh router
(`ciflow router` and three `ciflow serve` processes on loopback): the merged results equal
a single engine's for the same seeds and actions, and a vanished engine is an error."""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ciflow

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, free_port, start_process  # noqa: E402

TASK = "ciflow/Obstacle-v0"
ENGINES = ["scale-a", "scale-b", "scale-c"]


@pytest.fixture(scope="module")
def cluster():
    """(router endpoint, {engine name: process}) of a router with three engines."""
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    router = f"tcp/127.0.0.1:{free_port()}"
    processes = [start_process([str(BINARY), "router", "--listen", router])]
    engines = {}
    for name in ENGINES:
        engines[name] = start_process([
            sys.executable, "-m", "ciflow", "serve", "--name", name, "--connect", router,
            "--listen", f"tcp/127.0.0.1:{free_port()}"])
    processes += engines.values()
    yield router, engines
    for process in processes:
        process.terminate()
        process.wait(timeout=10)


def rollout(envs, steps: int = 850) -> list[np.ndarray]:
    """Observations, rewards, flags and an info column of `steps` seeded random steps
    (past the task's 800-step episodes, so every environment autoresets)."""
    actions = np.random.default_rng(3).uniform(-1.0, 1.0, (steps, envs.num_envs, 2))
    observations, _ = envs.reset(seed=7)
    trace = [observations]
    for action in actions:
        observations, rewards, terminated, truncated, info = envs.step(action)
        trace += [observations, rewards, terminated, truncated, info["is_success"]]
    return trace


def test_environments_spread_over_engines_step_as_on_one(cluster):
    router, _ = cluster
    spread = gym.make_vec(TASK, num_envs=10, engine=router, engines=ENGINES, obstacles=2)
    alone = gym.make_vec(TASK, num_envs=10, engine=router, engines=ENGINES[:1], obstacles=2)
    try:
        assert spread.unwrapped.engine_names == ENGINES
        assert spread.unwrapped._shares == [4, 3, 3]
        merged, single = rollout(spread), rollout(alone)
        ended = [t | u for t, u in zip(merged[3::5], merged[4::5])]
        assert np.any(ended, axis=0).all(), "every episode ended: autoreset is exercised"
        for a, b in zip(merged, single):
            np.testing.assert_array_equal(a, b)
        # An engine's refusal keeps its code and names the engine.
        actions = np.zeros((10, 2))
        actions[8] = np.nan
        with pytest.raises(ciflow.CiflowError, match="engine `scale-c`") as refused:
            spread.step(actions)
        assert refused.value.code == "not_finite"
    finally:
        spread.close()
        alone.close()


def test_a_row_of_reset_options_reaches_its_environment_on_whichever_engine(cluster):
    router, _ = cluster
    contexts = np.column_stack([np.linspace(-0.4, 0.4, 5), np.zeros(5), np.full(5, 0.8),
                                np.linspace(-0.5, 0.5, 5)])
    envs = gym.make_vec(TASK, num_envs=5, engine=router, engines=ENGINES, obstacles=1,
                        context=contexts)
    try:
        assert envs.unwrapped._shares == [2, 2, 1]
        observations, _ = envs.reset(seed=0)
        np.testing.assert_array_equal(observations[:, 4:], contexts)
    finally:
        envs.close()


def test_every_engine_serving_the_task_is_found_in_name_order(cluster):
    router, _ = cluster
    envs = gym.make_vec(TASK, num_envs=4, engine=router, engines="*", obstacles=1)
    try:
        assert envs.unwrapped.engine_names == sorted(ENGINES)
        assert envs.unwrapped._shares == [2, 1, 1]
    finally:
        envs.close()
    with pytest.raises(ciflow.EngineUnreachable, match="nope"):
        gym.make_vec(TASK, num_envs=4, engine=router, engines=["scale-a", "nope"])
    with pytest.raises(ValueError, match="twice"):
        gym.make_vec(TASK, num_envs=4, engine=router, engines=["scale-a", "scale-a"])
    with pytest.raises(ValueError, match="engine names together"):
        gym.make_vec(TASK, num_envs=4, engine=router, engines=["*", "scale-a"])
    # A name no engine can have is refused at once, without the grace a late engine gets.
    started = time.monotonic()
    with pytest.raises(ValueError, match="engine name `no such` must be"):
        gym.make_vec(TASK, num_envs=4, engine=router, engines=["scale-a", "no such"])
    assert time.monotonic() - started < 1.0


def test_every_engine_of_none_is_an_unreachable_error():
    """``engines="*"`` through a router that no engine joined."""
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    router = f"tcp/127.0.0.1:{free_port()}"
    alone = start_process([str(BINARY), "router", "--listen", router])
    try:
        with pytest.raises(ciflow.EngineUnreachable, match="no engine serving ciflow/Obstacle-v0"):
            gym.make_vec(TASK, num_envs=2, engine=router, engines="*")
    finally:
        alone.terminate()
        alone.wait(timeout=10)


def thread_policies(pid: int) -> dict[str, set[int]]:
    """The scheduling policies of process ``pid``'s threads by thread name (Linux:
    field 41 of ``/proc/<pid>/task/*/stat``; 0 the normal policy, 3 ``SCHED_BATCH``)."""
    policies: dict[str, set[int]] = {}
    for stat in Path(f"/proc/{pid}/task").glob("*/stat"):
        try:
            text = stat.read_text()
        except FileNotFoundError:  # a thread that ended meanwhile
            continue
        name = text[text.index("(") + 1:text.rindex(")")]
        # The fields after the name's closing parenthesis start at field 3.
        policies.setdefault(name, set()).add(int(text[text.rindex(")") + 1:].split()[41 - 3]))
    return policies


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduling policies")
def test_engines_run_all_their_threads_as_batch_threads(cluster):
    """``python -m ciflow serve`` schedules its engine as ``ciflow serve`` does, so that
    clients sharing its cores are not preempted when it wakes."""
    _, engines = cluster
    for name, process in engines.items():
        policies = thread_policies(process.pid)
        # Zenoh gives its shared-memory watchdogs a real-time policy of its own, and the
        # threads numpy's BLAS started at import, before the engine (named after the
        # process, as its main thread), keep the policy they had: they sleep meanwhile.
        engine = {policy for thread, found in policies.items()
                  if not thread.startswith(("Watchdog", "python")) for policy in found}
        assert engine == {3}, (name, policies)
        assert len(policies) > 4, (name, policies)
    # Negative control: this process's threads run under the normal policy, and the same
    # reading tells them apart.
    assert 0 in set().union(*thread_policies(os.getpid()).values())


def test_an_engine_still_starting_is_waited_for(cluster):
    """A named engine that does not answer yet (started a moment later, or linked to a
    peer's client only after the router's gossip) is asked again for a moment
    (`spread::JOIN_GRACE`): here it starts more than the second a single request retries
    an unrouted query for, so only the grace finds it."""
    router, _ = cluster
    late: list[subprocess.Popen] = []
    starter = threading.Timer(1.2, lambda: late.append(subprocess.Popen(
        [str(BINARY), "serve", "--name", "scale-late", "--connect", router,
         "--listen", f"tcp/127.0.0.1:{free_port()}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)))
    starter.start()
    try:
        envs = gym.make_vec(TASK, num_envs=4, engine=router, engines=["scale-a", "scale-late"],
                            obstacles=1)
        assert envs.unwrapped.engine_names == ["scale-a", "scale-late"]
        envs.reset(seed=0)
        envs.step(np.zeros((4, 2)))
        envs.close()
    finally:
        starter.join()
        for process in late:
            process.terminate()
            process.wait(timeout=10)


def test_engines_started_without_options_on_one_machine_all_meet(private_default_endpoint):
    """The first `ciflow serve` listens on the default endpoint, the next ones find it
    taken and join it: a client of the default endpoint reaches every one of them."""
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    engines = [start_process([str(BINARY), "serve", "--name", name])
               for name in ("zero-a", "zero-b")]
    try:
        # "*" is every engine reachable when asked; the second engine's queryables reach
        # a new client through the first one a moment after it says it is ready.
        deadline = time.monotonic() + 10.0
        while len(ciflow.discover()) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        envs = gym.make_vec(TASK, num_envs=4, engines="*", obstacles=1)
        assert envs.unwrapped.engine_names == ["zero-a", "zero-b"]
        envs.reset(seed=0)
        envs.step(np.zeros((4, 2)))
        envs.close()
    finally:
        for engine in engines:
            engine.terminate()
            engine.wait(timeout=10)


def test_an_engine_that_disappears_is_an_error_not_a_hang(cluster):
    router, engines = cluster
    envs = gym.make_vec(TASK, num_envs=6, engine=router, engines=ENGINES, obstacles=1)
    envs.reset(seed=0)
    envs.step(np.zeros((6, 2)))
    engines["scale-c"].kill()
    engines["scale-c"].wait(timeout=10)
    started = time.monotonic()
    with pytest.raises(ciflow.EngineUnreachable, match="engine `scale-c`"):
        for _ in range(100):
            envs.step(np.zeros((6, 2)))
    assert time.monotonic() - started < 15.0
    envs.close()
