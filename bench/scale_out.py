"""Env-steps/s of one Gymnasium vector environment spread over 1 and then 2 engines
(`gym.make_vec(..., engines=[...])`), measured one after the other in one run; the engines
are started by `bench/scale_out.sh`, each pinned to its own core with one stepping thread.
Two ways of joining are measured: as a Zenoh client of the router (every request passes
through it) and as a Zenoh peer that the router introduces to the engines (requests go
straight to them). Two tasks: the limit cycle, whose step is cheap beside the request
around it (also with 16 384 environments, where the per-request cost counts for less),
and the Panda pouring, whose ten 1 ms substeps make the engines the work.

Each measurement also reads the CPU time every process spent per step (`/proc`): the
engines', the router's and this client's. With one engine, the engine's share of the step
is all a second engine can halve; the client and the router work per request, so the
ratio cannot pass Amdahl's bound 2 / (2 - share), printed beside it (from the
rounds' medians, so a noisy round's ratio may land above it).

Each round also steps the same environments in one process on one and then two threads,
no Zenoh (`bridge/examples/in_process_steps.rs`, about 2 s each): two cores give no more
than that ratio without serving either, so it is printed beside the engines' ratio.

    python bench/scale_out.py ROUTER_ENDPOINT ENGINE_A ENGINE_B IN_PROCESS_STEPS_BINARY \
        router=PID,ENGINE_A=PID,ENGINE_B=PID
"""

import json
import os
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


def cpu_seconds(pid: int) -> float:
    """User and system CPU time the process `pid` has spent, all its threads."""
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def steps_per_second(task: str, num_envs: int, engines: list[str], processes: dict[str, int],
                     **join) -> tuple[float, dict[str, float]]:
    """Env-steps/s, and the seconds of CPU per step of the engines used, the router and
    this client (`processes`: pid by name)."""
    envs = gym.make_vec(task, num_envs=num_envs, engines=engines, **join)
    # Zero desired acceleration: every task accepts it, and the Panda holds its pose.
    actions = np.zeros((num_envs,) + envs.single_action_space.shape)
    envs.reset(seed=0)
    for _ in range(20):  # warm-up
        envs.step(actions)
    watched = {name: pid for name, pid in processes.items()
               if name in engines or name == "router"}
    watched["client"] = os.getpid()
    cpu = {name: cpu_seconds(pid) for name, pid in watched.items()}
    steps, started = 0, time.perf_counter()
    while time.perf_counter() - started < SECONDS:
        envs.step(actions)
        steps += 1
    elapsed = time.perf_counter() - started
    cpu = {name: (cpu_seconds(pid) - cpu[name]) / steps for name, pid in watched.items()}
    cpu["step"] = elapsed / steps
    envs.close()
    return steps * num_envs / elapsed, cpu


def in_process_steps_per_second(binary: str, task: str, num_envs: int, threads: int,
                                 steps: int) -> float:
    """Env-steps/s of the environments stepped in process (no Zenoh) on `threads` threads."""
    run = subprocess.run([binary, task, str(num_envs), str(threads), str(steps)],
                         capture_output=True, text=True, check=True)
    return json.loads(run.stdout)["env_steps_per_s"]


def cpu_summary(engines: list[str], cpus: list[dict[str, float]]) -> str:
    """Median CPU ms per step of each process over the rounds."""
    def ms(name):
        return np.median([cpu[name] for cpu in cpus]) * 1e3
    return (f"engine{'s' if len(engines) > 1 else ''} "
            + " + ".join(f"{ms(engine):.2f}" for engine in engines)
            + f", client {ms('client'):.2f}, router {ms('router'):.2f}")


def amdahl(engine: str, cpus: list[dict[str, float]]) -> str:
    """The one engine's median share of a step's time and the ratio it bounds."""
    share = min(1.0, float(np.median([cpu[engine] / cpu["step"] for cpu in cpus])))
    return (f"one engine busy {100 * share:.0f} % of a step: a second can halve only that, "
            f"ratio about {2 / (2 - share):.2f} at most (the rounds vary)")


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
    processes = {name: int(pid) for name, pid in
                 (entry.split("=") for entry in sys.argv[5].split(","))}
    print(f"One stepping thread per engine; {ROUNDS} rounds of {SECONDS:.0f} s on 1 then 2 "
          "engines: median (range) of the rounds")
    with tempfile.TemporaryDirectory() as directory:
        joins = (("client of the router", {"engine": router}),
                 ("peer via the router", {"zenoh_config": peer_config(router, Path(directory))}))
        for task, num_envs in RUNS:
            # The machine's load drifts: each round measures everything, side by side.
            served = {how: [] for how, _ in joins}
            cpus = {how: ([], []) for how, _ in joins}
            in_process = []
            for _ in range(ROUNDS):
                for how, join in joins:
                    (one, cpu_one), (two, cpu_two) = (
                        steps_per_second(task, num_envs, engines, processes, **join)
                        for engines in ([a], [a, b]))
                    served[how].append((one, two))
                    cpus[how][0].append(cpu_one)
                    cpus[how][1].append(cpu_two)
                # About 2 s per measurement, at the rate one engine just served.
                steps = max(5, round(2.0 * served[joins[0][0]][-1][0] / num_envs))
                in_process.append(tuple(
                    in_process_steps_per_second(in_process_binary, task, num_envs, threads, steps)
                    for threads in (1, 2)))
            print(f"  {task}, {num_envs} environments:")
            for how, rounds in served.items():
                print(f"    1 then 2 engines, {how}: {summary(rounds)}  (goal >= 1.7)")
                one, two = cpus[how]
                print(f"      CPU ms per step, 1 engine: {cpu_summary([a], one)}; "
                      f"2 engines: {cpu_summary([a, b], two)}")
                print(f"      {amdahl(a, one)}")
            print(f"    1 then 2 threads in one process, no Zenoh: {summary(in_process)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
