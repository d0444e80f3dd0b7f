"""Env-steps/s of one Gymnasium vector environment spread over 1 and then 2 engines
(`gym.make_vec(..., engines=[...])`), measured one after the other in one run; the engines
are started by `bench/scale_out.sh`, each pinned to its own core with one stepping thread.
Two ways of joining are measured: as a Zenoh client of the router (every request passes
through it) and as a Zenoh peer that the router introduces to the engines (requests go
straight to them).

    python bench/scale_out.py ROUTER_ENDPOINT ENGINE_A ENGINE_B
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import ciflow  # noqa: F401  (registers the environments)

TASK, NUM_ENVS, SECONDS = "ciflow/LimitCycle-v0", 4096, 10.0


def steps_per_second(engines: list[str], **join) -> float:
    envs = gym.make_vec(TASK, num_envs=NUM_ENVS, engines=engines, **join)
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


def peer_config(router: str, directory: Path) -> str:
    """A standard Zenoh configuration joining as a peer through `router`: the router's
    gossip tells it where the engines listen, and it connects to them directly."""
    path = directory / "peer.json5"
    path.write_text(json.dumps({
        "mode": "peer",
        "connect": {"endpoints": [router]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
    }))
    return str(path)


def main() -> int:
    router, a, b = sys.argv[1:4]
    print(f"{TASK}, {NUM_ENVS} environments, {SECONDS:.0f} s each, one stepping thread per engine")
    with tempfile.TemporaryDirectory() as directory:
        for how, join in (("client of the router", {"engine": router}),
                          ("peer via the router", {"zenoh_config": peer_config(router, Path(directory))})):
            one = steps_per_second([a], **join)
            two = steps_per_second([a, b], **join)
            print(f"  {how}: 1 engine {one / 1e6:6.3f}, 2 engines {two / 1e6:6.3f} "
                  f"M env-steps/s, ratio {two / one:.2f}  (goal >= 1.7)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
