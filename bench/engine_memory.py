"""Resident memory of an engine per 1000 environments of each task: for each task a fresh
`ciflow serve` process is started here and its resident set size (VmRSS) read before and
after each of SESSIONS 1000-environment sessions is made and reset. The first sessions'
growth includes one-time costs (thread pools, the task's shared data, and Zenoh's shared
memory: the engine's 16 MiB pool in the first session, zenoh-shm's watchdog with its 8 MiB
channel and the client's mapped segment in the second), so the cost per 1000 environments
is the median growth of the sessions after the first two, whose growths are printed
beside it. Then each session in turn steps for an episode's length (zero actions,
next-step autoreset), and the growths this adds are printed the same way: what an engine
that has been stepping holds on top.

    python bench/engine_memory.py [PATH_TO_CIFLOW]
"""

import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import ciflow  # noqa: F401  (registers the environments)

ROOT = Path(__file__).resolve().parent.parent
ENVS = 1000
SESSIONS = 5
TASKS = [
    ("ciflow/LimitCycle-v0", {}),
    ("ciflow/Obstacle-v0", {"obstacles": 3}),
    ("ciflow/Lasa-v0", {}),
    ("ciflow/Pouring-v0", {}),
    ("ciflow/Reach-v0", {"urdf": str(ROOT / "engine/tests/assets/ur5e.urdf"), "tool": "tool0"}),
]


def resident_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError("no VmRSS")


def growths(sizes: list[int]) -> list[float]:
    """MiB between consecutive sizes in KiB."""
    return [(after - before) / 1024 for before, after in zip(sizes, sizes[1:])]


def engine_growth(binary: str, task: str, kwargs: dict) -> tuple[list[float], list[float]]:
    """MiB an engine grows by when a client makes and resets ENVS environments of task,
    for each of SESSIONS sessions in turn (all kept open); then MiB it grows by while
    each session in turn steps for an episode's length."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    engine = subprocess.Popen([binary, "serve", "--listen", endpoint, "--name", "memory"],
                              stdout=subprocess.PIPE, text=True)
    try:
        while "ready" not in engine.stdout.readline():
            if engine.poll() is not None:
                raise RuntimeError(f"{binary} serve did not start")
        sizes, sessions = [resident_kib(engine.pid)], []
        for _ in range(SESSIONS):
            envs = gym.make_vec(task, num_envs=ENVS, engine=endpoint, **kwargs)
            envs.reset(seed=0)
            sessions.append(envs)
            time.sleep(0.2)
            sizes.append(resident_kib(engine.pid))
        stepped = [sizes[-1]]
        for envs in sessions:
            actions = np.zeros(envs.action_space.shape)
            for _ in range(envs.task_spec["max_episode_steps"]):
                envs.step(actions)
            stepped.append(resident_kib(engine.pid))
        for envs in sessions:
            envs.close()
        return growths(sizes), growths(stepped)
    finally:
        engine.terminate()
        engine.wait(timeout=10)


def main() -> int:
    binary = sys.argv[1] if len(sys.argv) > 1 else str(ROOT / "target/release/ciflow")
    print(f"engine resident memory per {ENVS} environments (made and reset, fresh engine "
          f"each, {SESSIONS} sessions), then while each session steps an episode's length: "
          f"median growth of sessions 3-{SESSIONS}, then every session's growth")
    for task, kwargs in TASKS:
        made, stepped = engine_growth(binary, task, kwargs)
        for what, growth in (("made and reset", made), ("then stepped", stepped)):
            steady = statistics.median(growth[2:])
            each = " ".join(f"{g:5.1f}" for g in growth)
            print(f"  {task:24s} {what:15s} {steady:6.1f} MiB   ({each})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
