"""A stable policy beside an external controller, in plain Python (no Gymnasium): a 1 kHz
loop asks a served policy for ``q̈_des`` every millisecond and prints the latency
distribution and the missed 1 ms deadlines.

    ciflow serve --listen tcp/127.0.0.1:7447 --name lab --policy pour=out/pouring/policy
    python python_client/examples/control_loop.py tcp/127.0.0.1:7447 pour [--seconds 60]

The plant is a stand-in double integrator ``q̈ = a`` (the joint-space behaviour of a
computed-torque arm); on a robot, ``q``, ``q̇`` come from the encoders and ``q̈_des`` goes to
the torque controller. The Rust twin is ``bridge/examples/control_loop.rs``.
"""

import argparse
import time

import numpy as np

import ciflow

PERIOD = 0.001  # s: 1 kHz
SPIN = 100e-6  # s: sleep until this long before a deadline, then spin


def middle(low, high) -> np.ndarray:
    m = (np.asarray(low, dtype=float) + np.asarray(high, dtype=float)) / 2.0
    return np.where(np.isfinite(m), m, 0.0)


def start_state(policy: ciflow.Policy, engine: str) -> tuple[np.ndarray, np.ndarray]:
    """At rest in the middle of the task's position range and context box; a zero context
    when the policy's task was built with other arguments than the listed spec's."""
    info = next(e for e in ciflow.discover(engine) if e["name"] == policy.engine)
    spec = next(t["spec"] for t in info["tasks"] if t["spec"]["id"] == policy.task)
    d, c = policy.action_dim, policy.observation_dim - 2 * policy.action_dim
    positions = spec["observation_space"]
    q = middle(positions["low"][:d], positions["high"][:d])
    box = spec["context_space"]
    context = middle(box["low"], box["high"]) if len(box["low"]) == c else np.zeros(c)
    return q, context


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("engine", help="endpoint or engine name")
    parser.add_argument("policy", help="the served policy's name")
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()

    policy = ciflow.Policy(args.policy, engine=args.engine)
    q, context = start_state(policy, args.engine)
    qd = np.zeros(policy.action_dim)

    periods = max(int(round(args.seconds / PERIOD)), 1)
    latencies, misses, period = [], 0, 0
    start = time.perf_counter()
    while period < periods:
        deadline = start + PERIOD * (period + 1)
        called = time.perf_counter()
        action = policy.act(np.concatenate([q, qd, context]))
        answered = time.perf_counter()
        latencies.append(answered - called)
        qd += action * PERIOD
        q += qd * PERIOD
        period += 1
        if answered > deadline:
            # This period is missed, and so is every one the late answer ran into.
            skipped = min(int((answered - deadline) / PERIOD), periods - period)
            misses += 1 + skipped
            period += skipped
            continue
        rest = deadline - time.perf_counter() - SPIN
        if rest > 0:
            time.sleep(rest)
        while time.perf_counter() < deadline:
            pass

    us = np.sort(np.array(latencies)) * 1e6
    print(f"{policy.task} at 1 kHz for {args.seconds:.1f} s")
    print(f"act over Zenoh (Python): {len(us)} calls, median {np.median(us):.1f} us, "
          f"p99 {np.quantile(us, 0.99):.1f} us, max {us[-1]:.1f} us, "
          f"missed {misses} of {periods} deadlines ({100 * misses / periods:.3f} %)")
    print(f"final joint speed {np.linalg.norm(qd):.4f} rad/s")


if __name__ == "__main__":
    main()
