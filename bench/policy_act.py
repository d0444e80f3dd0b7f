"""Policies in the engine, measured side by side in one run (``make`` not needed):

* ``act`` of one observation over Zenoh (loopback round trip, median of N) next to the
  raw ``ping`` round trip, and ``act`` of a batch of 1024 observations (per observation);
* pacing of a policy run: ``run`` at speed 1 for 200 control periods (2 s simulated),
  wall-clock time until its last telemetry sample, and at speed 0 (as fast as possible).

Usage: ``.venv/bin/python bench/policy_act.py [--ciflow target/release/ciflow]`` (trains a
small obstacle policy with ``ciflow demos`` + ``ciflow train`` in a temporary directory).
"""

import argparse
import os
import socket
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import ciflow
from ciflow import _native


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def median_us(fn, n: int) -> float:
    times = []
    for _ in range(n):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e6


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    default = Path(os.environ.get("CARGO_TARGET_DIR", root / "target")) / "release" / "ciflow"
    parser = argparse.ArgumentParser()
    parser.add_argument("--ciflow", default=str(default))
    parser.add_argument("-n", type=int, default=2000)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as scratch:
        run = lambda *a: subprocess.run([args.ciflow, *map(str, a)], check=True,  # noqa: E731
                                        capture_output=True)
        run("demos", "--task", "obstacle-avoidance", "--episodes", "4", "--kwarg",
            "obstacles=1", "--out", f"{scratch}/demos")
        run("train", "--task", "obstacle-avoidance", "--demos", f"{scratch}/demos", "--out",
            f"{scratch}/avoid", "--epochs", "2")
        endpoint, name = f"tcp/127.0.0.1:{free_port()}", "bench-policy"
        engine = subprocess.Popen(
            [args.ciflow, "serve", "--listen", endpoint, "--name", name, "--telemetry-hz",
             "1000", "--policy", f"avoid={scratch}/avoid", "--policy-kwarg", "obstacles=1"],
            stdout=subprocess.PIPE, text=True)
        try:
            assert "ready" in engine.stdout.readline()
            client = _native.ClientHandle.open(connect=[endpoint])
            observation = np.array([-0.8, 0.3, 0.1, -0.2, 0.0, -0.7, 0.8, 0.1]).tobytes()
            batch = np.tile(np.frombuffer(observation), 1024).tobytes()
            env = gym.make("ciflow/Obstacle-v0", engine=endpoint, obstacles=1)
            env.reset(seed=0)
            ping = median_us(lambda: env.unwrapped.expert_action(), args.n)
            one = median_us(lambda: client.act(name, "avoid", observation), args.n)
            many = median_us(lambda: client.act(name, "avoid", batch), max(args.n // 20, 20))
            print(f"expert query (round trip baseline): {ping:8.1f} us")
            print(f"act, 1 observation:                 {one:8.1f} us  ({one / ping:.2f}x)")
            print(f"act, 1024 observations:             {many:8.1f} us  "
                  f"({many / 1024:.2f} us per observation)")

            control = env.unwrapped.attach()
            feed = control.telemetry(timeout=10)
            time.sleep(0.3)
            for speed in (1.0, 0.0):
                env.reset(seed=0)
                while feed.get(timeout=0.2) is not None:
                    pass
                start = time.perf_counter()
                control.run_policy("avoid", speed=speed, steps=200)
                last = None
                for sample in feed:
                    last = sample
                    if not sample["running"]:
                        break
                wall = time.perf_counter() - start
                print(f"run speed {speed:g}, 200 steps ({last['time']:.2f} s simulated): "
                      f"{wall:.3f} s wall")
            env.close()
        finally:
            engine.terminate()
            engine.wait()


if __name__ == "__main__":
    main()
