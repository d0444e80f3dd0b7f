"""Resident memory of an engine per 1000 environments of each task: for each task a fresh
`ciflow serve` process is started here and its resident set size (VmRSS) read before and
after each of two 1000-environment sessions is made and reset. The first session's
growth includes one-time costs (thread pools, the task's shared data); the second's is
the cost per 1000 environments.

    python bench/engine_memory.py [PATH_TO_CIFLOW]
"""

import socket
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym

import ciflow  # noqa: F401  (registers the environments)

ROOT = Path(__file__).resolve().parent.parent
ENVS = 1000
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


def engine_growth(binary: str, task: str, kwargs: dict) -> tuple[float, float]:
    """MiB an engine grows by when a client makes and resets ENVS environments of task,
    for a first and a second session."""
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
        for _ in range(2):
            envs = gym.make_vec(task, num_envs=ENVS, engine=endpoint, **kwargs)
            envs.reset(seed=0)
            sessions.append(envs)
            time.sleep(0.2)
            sizes.append(resident_kib(engine.pid))
        for envs in sessions:
            envs.close()
        return (sizes[1] - sizes[0]) / 1024, (sizes[2] - sizes[1]) / 1024
    finally:
        engine.terminate()
        engine.wait(timeout=10)


def main() -> int:
    binary = sys.argv[1] if len(sys.argv) > 1 else str(ROOT / "target/release/ciflow")
    print(f"engine resident memory per {ENVS} environments (made and reset, fresh engine "
          "each): first session (with one-time costs), second session")
    for task, kwargs in TASKS:
        first, second = engine_growth(binary, task, kwargs)
        print(f"  {task:24s} {first:8.1f} MiB {second:8.1f} MiB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
