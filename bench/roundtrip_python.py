"""Python side of the round-trip benchmark, measured side by side in one run:

* raw Zenoh query round trip from Python (eclipse-zenoh querier on the engine's ``ping``,
  with a payload the size of a step request);
* ``env.step`` through ``gymnasium.make`` (all of Gymnasium's default wrappers);
* batched env-steps/s through ``gymnasium.make_vec`` (one request per step), with the CPU
  time and page faults of this process per step.

Usage: python bench/roundtrip_python.py ENDPOINT
"""

import resource
import sys
import time

import gymnasium as gym
import numpy as np
import zenoh

import ciflow

TASK = "ciflow/LimitCycle-v0"
WARMUP, SAMPLES = 500, 5000


def timed(call) -> np.ndarray:
    for _ in range(WARMUP):
        call()
    samples = np.empty(SAMPLES)
    for i in range(SAMPLES):
        start = time.perf_counter()
        call()
        samples[i] = time.perf_counter() - start
    return samples * 1e6


def best(runs):
    return min(runs, key=lambda s: np.median(s))


def main(endpoint: str) -> None:
    env = gym.make(TASK, engine=endpoint)
    engine = env.unwrapped.engine_name
    env.reset(seed=0)
    action = env.unwrapped.expert_action()

    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["{endpoint}"]')
    session = zenoh.open(config)
    ping = session.declare_querier(
        f"ciflow/v2/engine/{engine}/ping", consolidation=zenoh.ConsolidationMode.NONE
    )
    payload = bytes(60)

    def raw():
        for reply in ping.get(payload=payload):
            reply.ok.payload.to_bytes()
            break

    def step():
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    raw_runs, step_runs = [], []
    for _ in range(3):
        raw_runs.append(timed(raw))
        step_runs.append(timed(step))
    raw_s, step_s = best(raw_runs), best(step_runs)
    print(f"round trip from Python ({TASK}, {SAMPLES} samples, best of 3 interleaved runs)")
    for name, s in (("raw Zenoh query (ping)", raw_s), ("gymnasium env.step", step_s)):
        print(f"  {name:<24} median {np.median(s):7.1f} µs   p99 {np.percentile(s, 99):7.1f} µs")
    print(
        f"  ratio step / raw         median {np.median(step_s) / np.median(raw_s):7.2f}x     "
        f"p99 {np.percentile(step_s, 99) / np.percentile(raw_s, 99):7.2f}x"
    )
    env.close()
    ping.undeclare()
    session.close()

    print(f"batched stepping from Python ({TASK}, gymnasium.make_vec; this process's CPU "
          "and page faults per step call)")
    for n in (1024, 4096, 16384, 65536):
        envs = gym.make_vec(TASK, num_envs=n, engine=endpoint)
        envs.reset(seed=0)
        actions = np.zeros((n,) + envs.single_action_space.shape)
        for _ in range(5):
            envs.step(actions)
        rounds = max(10, min(400, 2_000_000 // n))
        usage, start = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
        for _ in range(rounds):
            envs.step(actions)
        elapsed = time.perf_counter() - start
        used = resource.getrusage(resource.RUSAGE_SELF)
        cpu = used.ru_utime + used.ru_stime - usage.ru_utime - usage.ru_stime
        print(
            f"  num_envs {n:>7}: {rounds * n / elapsed:>12.0f} env-steps/s   "
            f"({elapsed * 1e3 / rounds:.2f} ms per step call; client CPU "
            f"{cpu * 1e3 / rounds:.2f} ms, {(used.ru_minflt - usage.ru_minflt) / rounds:.1f} "
            "page faults)"
        )
        envs.close()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ciflow.DEFAULT_ENDPOINT)
