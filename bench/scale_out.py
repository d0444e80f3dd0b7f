"""Env-steps/s of one Gymnasium vector environment spread over 1 and then 2 engines
(`gym.make_vec(..., engines=[...])`), measured one after the other in one run; the engines
are started by `bench/scale_out.sh`, each pinned to its own core with one stepping thread.

    python bench/scale_out.py ROUTER_ENDPOINT ENGINE_A ENGINE_B
"""

import sys
import time

import gymnasium as gym
import numpy as np

import ciflow  # noqa: F401  (registers the environments)

TASK, NUM_ENVS, SECONDS = "ciflow/LimitCycle-v0", 4096, 10.0


def steps_per_second(router: str, engines: list[str]) -> float:
    envs = gym.make_vec(TASK, num_envs=NUM_ENVS, engine=router, engines=engines)
    actions = np.zeros((NUM_ENVS, 2))
    envs.reset(seed=0)
    for _ in range(20):  # warm-up
        envs.step(actions)
    steps, started = 0, time.perf_counter()
    while time.perf_counter() - started < SECONDS:
        envs.step(actions)
        steps += 1
    elapsed = time.perf_counter() - started
    envs.close()
    return steps * NUM_ENVS / elapsed


def main() -> int:
    router, a, b = sys.argv[1:4]
    one = steps_per_second(router, [a])
    two = steps_per_second(router, [a, b])
    print(f"{TASK}, {NUM_ENVS} environments, {SECONDS:.0f} s each, one stepping thread per engine")
    print(f"  1 engine : {one / 1e6:6.3f} M env-steps/s")
    print(f"  2 engines: {two / 1e6:6.3f} M env-steps/s")
    print(f"  ratio 2 / 1 engines: {two / one:.2f}  (goal >= 1.7)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
