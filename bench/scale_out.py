"""Env-steps/s of one Gymnasium vector environment spread over 1 and then 2 engines
(`gym.make_vec(..., engines=[...])`), measured one after the other in one run; the engines
are started by `bench/scale_out.sh`, each pinned to its own core with one stepping thread.
Two ways of joining are measured: as a Zenoh client of the router (every request passes
through it) and as a Zenoh peer that the router introduces to the engines (requests go
straight to them). Two tasks: the limit cycle, whose step is cheap beside the request
around it (also with 16 384 environments, where the per-request cost counts for less),
and the Panda pouring, whose ten 1 ms substeps make the engines the work.

Each round also steps the same environments in one process on one and then two threads,
no Zenoh (`bridge/examples/in_process_steps.rs`, about 2 s each): two cores give no more
than that ratio without serving either, so it is printed beside the engines' ratio.

    python bench/scale_out.py ROUTER_ENDPOINT ENGINE_A ENGINE_B IN_PROCESS_STEPS_BINARY
"""

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import ciflow  # noqa: F401  (registers the environments)

RUNS = (("ciflow/LimitCycle-v0", 4096), ("ciflow/LimitCycle-v0", 16384),
        ("ciflow/Pouring-v0", 4096))
SECONDS, ROUNDS = 5.0, 3


def steps_per_second(task: str, num_envs: int, engines: list[str], **join) -> float:
    envs = gym.make_vec(task, num_envs=num_envs, engines=engines, **join)
    # Zero desired acceleration: every task accepts it, and the Panda holds its pose.
    actions = np.zeros((num_envs,) + envs.single_action_space.shape)
    envs.reset(seed=0)
    for _ in range(20):  # warm-up
        envs.step(actions)
    steps, started = 0, time.perf_counter()
    while time.perf_counter() - started < SECONDS:
        envs.step(actions)
        steps += 1
    elapsed = time.perf_counter() - started
    envs.close()
    return steps * num_envs / elapsed


def in_process_steps_per_second(binary: str, task: str, num_envs: int, threads: int,
                                 steps: int) -> float:
    """Env-steps/s of the environments stepped in process (no Zenoh) on `threads` threads."""
    run = subprocess.run([binary, task, str(num_envs), str(threads), str(steps)],
                         capture_output=True, text=True, check=True)
    return json.loads(run.stdout)["env_steps_per_s"]


def summary(rounds: list[tuple[float, float]]) -> str:
    """The rounds' median rates and the median (range) of their ratios."""
    one, two = (np.median([r[k] for r in rounds]) / 1e6 for k in (0, 1))
    ratios = [second / first for first, second in rounds]
    return (f"{one:6.3f}, then {two:6.3f} M env-steps/s, ratio {np.median(ratios):.2f} "
            f"({min(ratios):.2f}-{max(ratios):.2f})")


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
    router, a, b, in_process_binary = sys.argv[1:5]
    print(f"One stepping thread per engine; {ROUNDS} rounds of {SECONDS:.0f} s on 1 then 2 "
          "engines: median (range) of the rounds")
    with tempfile.TemporaryDirectory() as directory:
        joins = (("client of the router", {"engine": router}),
                 ("peer via the router", {"zenoh_config": peer_config(router, Path(directory))}))
        for task, num_envs in RUNS:
            # The machine's load drifts: each round measures everything, side by side.
            served = {how: [] for how, _ in joins}
            in_process = []
            for _ in range(ROUNDS):
                for how, join in joins:
                    served[how].append((steps_per_second(task, num_envs, [a], **join),
                                        steps_per_second(task, num_envs, [a, b], **join)))
                # About 2 s per measurement, at the rate one engine just served.
                steps = max(5, round(2.0 * served[joins[0][0]][-1][0] / num_envs))
                in_process.append(tuple(
                    in_process_steps_per_second(in_process_binary, task, num_envs, threads, steps)
                    for threads in (1, 2)))
            print(f"  {task}, {num_envs} environments:")
            for how, rounds in served.items():
                print(f"    1 then 2 engines, {how}: {summary(rounds)}  (goal >= 1.7)")
            print(f"    1 then 2 threads in one process, no Zenoh: {summary(in_process)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
