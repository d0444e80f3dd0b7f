"""`make demo`: the C-IFlows paper's experiments end to end, each step its own process,
the processes meeting only over Zenoh.

    python scripts/demo.py [--out out] [--jobs 2]

1. `ciflow serve` hosts every task (zero configuration: tcp/127.0.0.1:7447).
2. `python -m ciflow.record` rolls the experts out through `gymnasium.make` and writes the
   datasets; the pouring recorder publishes its episodes on Zenoh, where
3. `ciflow train --from-zenoh 440 --publish pouring`, started first, collects them, trains
   the stable policy and publishes each better checkpoint, which
4. the engine hot-loads (no restart) and runs closed-loop, while
5. `python -m ciflow.perturb` pushes the Panda's hand and moves the pot in that session.
6. `ciflow evaluate` / `ciflow stability` measure every policy; `scripts/report.py`
   writes out/report.md with the figures.

Jobs run `--jobs` at a time (default: one per core); each writes its log to
out/logs/<job>.log. A failed job skips the jobs that need it; the others still run, the
report marks what is missing, and the demo ends with the failed logs' tails and status 1.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field

from tqdm import tqdm

ROOT = pathlib.Path(__file__).resolve().parent.parent
CIFLOW = os.environ.get("CIFLOW", str(ROOT / "target" / "release" / "ciflow"))
ARMS = ROOT / "engine" / "tests" / "assets"
# The reach task's arms (README "Bring your own robot"): URDF, tool and home posture.
REACH_ARMS = {
    "ur5e": {"urdf": ARMS / "ur5e.urdf", "tool": "tool0", "home": "0,-1.57,1.57,-1.57,-1.57,0"},
    "iiwa14": {"urdf": ARMS / "iiwa14.urdf", "home": "0,0.5,0,-1.2,0,0.8,0"},
}
REACH_DEMOS = 500
PYTHON = os.environ.get("PYTHON", sys.executable)

# The experiments' sizes (the issue's numbers; see README "The experiments").
LIMIT_CYCLE_TRAJECTORIES = (2, 5, 10)
SEEDS = (0, 1, 2)
OBSTACLE_COUNTS = (1, 2, 3)
OBSTACLE_DEMOS = 1000
# 440 pouring demonstrations: on 220 the policy came back onto its path within 2 s after
# 66-93 % of the pushes over three training seeds, on 440 in 88-95 % (README "Pouring").
POURING_DEMOS = 440
POURING_TEST_DEMOS = 40
POURING_FRACTIONS = (0.1, 0.3, 1.0)
# The learning curve's model that trains the unconstrained MLP beside it (fraction, seed):
# the demo's pouring policy's data and training seed.
POURING_CONTROL = (1.0, 0)
EVALUATION_EPISODES = 100
# Obstacle episodes take milliseconds each, and a collision rate near the 1 % target needs
# more than 100 of them to be told from 0 or 2 %.
OBSTACLE_EVALUATION_EPISODES = 1000
# Held-out seeds: far from the training seeds (episode i is reset with seed + i).
TEST_SEED = 100_000
# Every pouring demonstration (train and test) is pushed once on the hand, U(0, 40) N for
# 0.2 s in a random horizontal direction (the task's `push_force` option, DART-style noise
# injection): the demonstrations then show the expert returning to its path, which the
# flow needs to recover from the evaluation's pushes within 2 s (README "Pouring").
POURING_DEMO_OPTIONS = ["--option", "push_force=40"]
LIMIT_CYCLE_MODEL = ["--epochs", "40"]
# Closed-loop episodes of the limit-cycle models on each context set (the contexts are
# scheduled in turn, so each of the ten training phases is run ten times).
LIMIT_CYCLE_EVALUATION_EPISODES = 100
# The limit-cycle families: (name, training and held-out context sets of the task's
# `context_set` option, the field figure's contexts).
LIMIT_CYCLE_FAMILIES = (("limit-cycle", 0, 1, "0;0.5;1"),
                        ("limit-cycle-curled", 3, 4, "1;1.5;2"))
# 1000 demonstrations, two epochs, the last kept: about 2.5 CPU-minutes per model; ten
# epochs moved the generic network from 63.5 % to 69 % (README "Obstacle avoidance").
OBSTACLE_MODEL = ["--epochs", "2", "--keep", "last"]
# The paper's model beside it, for each count: the same recipe without the radial
# contractions, so the obstacle set enters the couplings' conditioners only through the
# permutation-invariant set encoder (README "Obstacle avoidance").
OBSTACLE_GENERIC = "generic"
OBSTACLE_GENERIC_MODEL = [*OBSTACLE_MODEL, "--contraction-layers", "0"]
# Each obstacle flow's stability check also drives the point mass at 100 Hz from rest
# anywhere in its range, as many times as it takes to see a rollout in a few hundred that
# never arrives (README "Obstacle avoidance", sampled control).
OBSTACLE_ROBOT_LOOP = ["--robot-loop", "--robot-starts", "400"]
# The behaviour-cloning MLP trained beside the 3-obstacle flow (`--baseline`), evaluated
# on the same held-out episodes.
OBSTACLE_BASELINE = "3-baseline"
# The perturbation script's run as a Rerun recording, beside the report.
PERTURB_RECORDING = "pouring_perturb.rrd"
# What the perturbation script does to the running pouring session (simulated seconds):
# a 0.2 s push on the hand, then the pot moved to another valid pose, where it stays:
# 5 cm along x, 8 cm along y, turned by 0.33 rad. (Turning it by 0.93 rad instead, most
# of the yaw range, saturates the joint accelerations and spills; `ciflow evaluate
# --perturb context` gives the rate over 100 random moves.)
PERTURB_PUSH = "link=6,force=0:-15:0,at=1.0,duration=0.2"
PERTURB_CONTEXT = "at=1.5,value=0.55:-0.1:0.05:0:0:-0.2"


@dataclass
class Job:
    """Commands run in order; `after` names the jobs whose outputs they read."""

    name: str
    commands: list[list[str]]
    after: list[str] = field(default_factory=list)
    # Where a command's stdout goes instead of the log (e.g. `ciflow stability --json`).
    stdout: pathlib.Path | None = None
    # Run instead of `commands` (jobs of several concurrent processes).
    action: object = None


class Runner:
    """Runs jobs as their dependencies finish, `slots` at a time, with one progress bar."""

    def __init__(self, logs: pathlib.Path, slots: int):
        self.logs = logs
        self.slots = slots
        self.processes: set[subprocess.Popen] = set()
        self.lock = threading.Lock()
        self.cancelled = False

    def spawn(self, command, log, stdout=None) -> subprocess.Popen:
        """Starts `command` with its output in `log` (stdout in `stdout` if given)."""
        with self.lock:
            if self.cancelled:
                raise RuntimeError("cancelled")
            process = subprocess.Popen(
                [str(c) for c in command], cwd=ROOT, stdin=subprocess.DEVNULL,
                stdout=stdout or log, stderr=log, text=True, start_new_session=True)
            self.processes.add(process)
        return process

    def finish(self, process: subprocess.Popen, command) -> None:
        status = process.wait()
        with self.lock:
            self.processes.discard(process)
        if status != 0:
            raise RuntimeError(f"`{' '.join(map(str, command))}` exited with {status}")

    def run_job(self, job: Job) -> float:
        start = time.monotonic()
        with open(self.logs / f"{job.name}.log", "w") as log:
            if job.action is not None:
                job.action(self, log)
            for command in job.commands:
                log.write(f"$ {' '.join(map(str, command))}\n")
                log.flush()
                if job.stdout is None:
                    self.finish(self.spawn(command, log), command)
                else:
                    with open(job.stdout, "w") as stdout:
                        self.finish(self.spawn(command, log, stdout), command)
        return time.monotonic() - start

    def run(self, jobs: list[Job]) -> tuple[dict[str, float], list[JobFailed]]:
        """Runs `jobs`; returns the seconds each finished job took, and the failures. A
        failed job's dependents are skipped; the jobs that do not need it still run."""
        names = {job.name for job in jobs}
        for job in jobs:
            unknown = set(job.after) - names
            if unknown:
                raise ValueError(f"job {job.name} waits for unknown jobs {sorted(unknown)}")
        waiting, running, done, failed = list(jobs), {}, {}, []
        bar = tqdm(total=len(jobs), unit="job", desc="demo", dynamic_ncols=True)
        with ThreadPoolExecutor(self.slots) as pool:
            try:
                self.schedule(pool, bar, waiting, running, done, failed)
            except BaseException:
                # Before the pool waits for its threads, which wait for the processes.
                self.cancel()
                raise
            finally:
                bar.close()
        return done, failed

    def schedule(self, pool, bar, waiting, running, done, failed) -> None:
        broken = set()
        while waiting or running:
            for job in [j for j in waiting if broken.intersection(j.after)]:
                waiting.remove(job)
                broken.add(job.name)
                bar.write(f"  {job.name:<28} skipped (needs a failed job)")
                bar.update()
            for job in [j for j in waiting if all(a in done for a in j.after)]:
                if len(running) >= self.slots:
                    break
                waiting.remove(job)
                running[pool.submit(self.run_job, job)] = job
            if not running:
                continue
            bar.set_postfix_str(", ".join(j.name for j in running.values()))
            finished, _ = wait(list(running), return_when=FIRST_COMPLETED)
            for future in finished:
                job = running.pop(future)
                try:
                    done[job.name] = future.result()
                    bar.write(f"  {job.name:<28} {done[job.name]:7.1f} s")
                except Exception as error:
                    failed.append(JobFailed(job, self.logs / f"{job.name}.log", error))
                    broken.add(job.name)
                    bar.write(f"  {job.name:<28} FAILED (see {failed[-1].log})")
                bar.update()

    def cancel(self) -> None:
        with self.lock:
            self.cancelled = True
            for process in self.processes:
                os.killpg(process.pid, signal.SIGTERM)


class JobFailed(Exception):
    def __init__(self, job: Job, log: pathlib.Path, error: Exception):
        super().__init__(f"job {job.name} failed: {error} (log: {log})")
        self.log = log


def wait_for_line(path: pathlib.Path, text: str, process: subprocess.Popen, timeout: float):
    """Waits until `text` appears in the file `path` written by `process`."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text():
            return
        if process.poll() is not None:
            raise RuntimeError(f"{process.args[0]} exited with {process.returncode} before "
                               f"printing `{text}` (see {path})")
        time.sleep(0.1)
    raise RuntimeError(f"no `{text}` in {path} after {timeout:.0f} s")


def plan(out: pathlib.Path) -> list[Job]:
    """The experiments as jobs; out/experiments has the layout scripts/report.py reads."""
    data, policies, exp = out / "data", out / "policies", out / "experiments"
    for d in (data, policies, exp / "pouring" / "nll", exp / "pouring" / "seeds",
              exp / "stability", exp / "robot_loop", exp / "reach", out / "figures"):
        d.mkdir(parents=True, exist_ok=True)

    def record(name, task, episodes, seed, dataset, *extra):
        return Job(name, [[PYTHON, "-m", "ciflow.record", "--task", task, "--episodes",
                           episodes, "--seed", seed, "--out", dataset, "--no-publish",
                           "--overwrite", "--quiet", *extra]])

    def evaluate(checkpoint, *extra):
        return [CIFLOW, "evaluate", "--checkpoint", checkpoint, *extra]

    def stability(name, checkpoint, after, *extra):
        return Job(f"stability-{name}",
                   [[CIFLOW, "stability", "--checkpoint", checkpoint, "--json", *extra]],
                   after=[after], stdout=exp / "stability" / f"{name}.json")

    # Longest chain first: the scheduler starts ready jobs in this order.
    jobs = []
    # Pouring: the trainer takes the recorder's episodes from Zenoh and publishes to the
    # engine, which runs the policy while the perturbation script pushes it.
    pouring_data, pouring_test = data / "pouring", data / "pouring-test"
    pouring = policies / "pouring"

    def record_and_train(runner: Runner, log):
        trainer_log = runner.logs / "pouring-trainer.log"
        shutil.rmtree(pouring_data, ignore_errors=True)  # the trainer writes a new dataset
        with open(trainer_log, "w") as tlog:
            trainer_command = [
                CIFLOW, "train", "--task", "pouring", "--from-zenoh", POURING_DEMOS, "--demos",
                pouring_data, "--out", pouring, "--publish", "pouring"]
            trainer = runner.spawn(trainer_command, tlog)
            wait_for_line(trainer_log, "waiting for", trainer, timeout=60)
            recorder = [PYTHON, "-m", "ciflow.record", "--task", "pouring", "--episodes",
                        POURING_DEMOS, "--seed", 0, "--recorder", "demo", "--quiet",
                        *POURING_DEMO_OPTIONS]
            log.write(f"$ {' '.join(map(str, recorder))}\n")
            log.flush()
            runner.finish(runner.spawn(recorder, log), recorder)
            runner.finish(trainer, trainer_command)

    jobs.append(Job("pouring-record-train", [], action=record_and_train))
    jobs.append(record("record-pouring-test", "pouring", POURING_TEST_DEMOS, TEST_SEED,
                       pouring_test, *POURING_DEMO_OPTIONS))
    jobs.append(Job("pouring-perturb", [[
        PYTHON, "-m", "ciflow.perturb", "--task", "pouring", "--policy", "pouring", "--seed",
        TEST_SEED, "--push", PERTURB_PUSH, "--context-step", PERTURB_CONTEXT, "--quiet",
        "--record", exp / "pouring" / "perturb.json", "--plot",
        out / "figures" / "pouring_perturb_script.png", "--rrd", out / PERTURB_RECORDING]],
        after=["pouring-record-train"]))
    # The closed-loop figures: held-out contexts undisturbed, pushed, and with the pot moved.
    pouring_modes = (("eval", []), ("push", ["--perturb", "push"]),
                     ("context", ["--perturb", "context"]))
    held_out = ["--episodes", EVALUATION_EPISODES, "--seed", TEST_SEED]
    for mode, extra in pouring_modes:
        episodes = [*held_out, *extra]
        jobs.append(Job(f"pouring-{mode}", [evaluate(
            pouring, *episodes, "--trajectories", 4, "--out",
            exp / "pouring" / f"{mode}.json")], after=["pouring-record-train"]))
        # The demonstrator in the same episodes: the reference beside the policy's figures.
        jobs.append(Job(f"pouring-expert-{mode}", [[
            CIFLOW, "evaluate", "--expert", "--task", "pouring", *episodes, "--out",
            exp / "pouring" / f"expert-{mode}.json"]]))
    jobs.append(stability("pouring-flow", pouring, "pouring-record-train", "--robot-loop",
                          "--negative-control"))
    # Joint limits (README "Joint limits"): the demo's policy beside the same recipe with
    # the Panda's limits built in (`--joint-range true`), through the computed-torque loop
    # from 100 starts drawn over the joint ranges, without and with a 40 N push on the hand.
    limited = policies / "pouring-joint-range"
    jobs.append(Job("pouring-joint-range", [[
        CIFLOW, "train", "--task", "pouring", "--demos", pouring_data, "--joint-range",
        "true", "--out", limited]], after=["pouring-record-train"]))
    for mode, extra in pouring_modes:
        jobs.append(Job(f"pouring-joint-range-{mode}", [evaluate(
            limited, *held_out, *extra, "--out", exp / "pouring" / f"joint-range-{mode}.json")],
            after=["pouring-joint-range"]))
    for name, checkpoint, after in (("flow", pouring, "pouring-record-train"),
                                    ("joint-range", limited, "pouring-joint-range")):
        for suffix, extra in (("", []), ("-pushed", ["--robot-push", "40"])):
            jobs.append(Job(f"robot-loop-{name}{suffix}", [[
                CIFLOW, "stability", "--checkpoint", checkpoint, "--json", "--starts", "100",
                "--robot-loop", "--robot-traces", "4", *extra]], after=[after],
                stdout=exp / "robot_loop" / f"{name}{suffix}.json"))
    # Bring your own robot (README): the reach task on two arms that are not the Panda,
    # given by URDF; recorded through gymnasium.make, trained with the unconstrained MLP
    # beside it, and both evaluated on new goals beside their expert.
    for arm, arguments in REACH_ARMS.items():
        kwargs = [arg for key, value in arguments.items() for arg in ("--kwarg", f"{key}={value}")]
        policy = policies / f"reach-{arm}"
        jobs.append(Job(f"reach-{arm}", [
            [PYTHON, "-m", "ciflow.record", "--task", "reach", *kwargs, "--episodes",
             REACH_DEMOS, "--seed", 0, "--out", data / f"reach-{arm}", "--no-publish",
             "--overwrite", "--quiet"],
            [CIFLOW, "train", "--task", "reach", "--demos", data / f"reach-{arm}", "--out",
             policy, "--baseline"],
            evaluate(policy, *held_out, "--out", exp / "reach" / f"{arm}.json"),
            evaluate(policy / "baseline", *held_out, "--out",
                     exp / "reach" / f"{arm}-baseline.json"),
            [CIFLOW, "evaluate", "--expert", "--task", "reach", *kwargs, *held_out, "--out",
             exp / "reach" / f"{arm}-expert.json"]]))
    # The pouring policy and the learning curve's models are the task's recipe (`ciflow
    # train`): every successful episode of their subset fitted, none held out for early
    # stopping, the last epoch kept, so n on the curve is n episodes fitted and the
    # held-out score comes from the separate test recording. The curve's three full-data
    # models (training seeds 0, 1, 2) are also run closed loop: the policy's figures over
    # training seeds.
    def curve_policy(fraction, seed):
        return policies / "pouring-curve" / f"{fraction}_seed{seed}"

    for fraction in POURING_FRACTIONS:
        # The whole dataset at 1.0: every demonstration that did not fail (the trainer
        # drops the others, so a count of all of them would be more than it has).
        count = [] if fraction == 1.0 else [round(fraction * POURING_DEMOS)]
        for seed in SEEDS:
            policy = curve_policy(fraction, seed)
            nll = exp / "pouring" / "nll"
            # The full-data model of seed 0 (the demo's policy again) trains the
            # unconstrained MLP beside it, with its budget and widths: the control.
            control = ["--baseline"] if (fraction, seed) == POURING_CONTROL else []
            jobs.append(Job(f"pouring-{fraction}-seed{seed}", [
                [CIFLOW, "train", "--task", "pouring", "--demos", pouring_data,
                 *(["--subset", *count] if count else []), "--seed", seed, "--out", policy,
                 *control],
                evaluate(policy, "--nll", pouring_data,
                         *(["--nll-subset", *count] if count else []),
                         "--seed", seed, "--out", nll / f"{fraction}_seed{seed}_train.json"),
                evaluate(policy, "--nll", pouring_test,
                         "--out", nll / f"{fraction}_seed{seed}_test.json"),
            ], after=["pouring-record-train", "record-pouring-test"]))
            if fraction == 1.0:
                seeds = exp / "pouring" / "seeds"
                jobs.append(Job(f"pouring-seed{seed}-closed-loop", [evaluate(
                    policy, *held_out, *extra, "--out", seeds / f"{mode}_seed{seed}.json")
                    for mode, extra in pouring_modes], after=[f"pouring-1.0-seed{seed}"]))
    # The unconstrained control on the policy's held-out episodes, pushes and pot moves,
    # and through the stability check the flows pass.
    control, trained = (curve_policy(*POURING_CONTROL) / "baseline",
                        "pouring-{}-seed{}".format(*POURING_CONTROL))
    jobs.append(Job("pouring-baseline", [evaluate(
        control, *held_out, *extra, "--out", exp / "pouring" / f"baseline-{mode}.json")
        for mode, extra in pouring_modes], after=[trained]))
    jobs.append(stability("pouring-baseline", control, trained))
    # Obstacle avoidance with 1, 2 and 3 obstacles, each by the default model and by the
    # generic one (+ the unconstrained baseline for 3).
    obstacle_record_seed = 0

    def obstacle_evaluations(policy, k, results):
        """The held-out episodes, and the demonstrations' own (the recording's seeds give
        its contexts and starts), which `ciflow evaluate` divides into those the model was
        fitted to and those its training held out: whether a model fits its data, not
        only generalises."""
        task = ["--kwarg", f"obstacles={k}"]
        return [evaluate(policy, *task, "--episodes", OBSTACLE_EVALUATION_EPISODES,
                         "--seed", TEST_SEED, "--trajectories", 8, "--out", results / "eval.json"),
                evaluate(policy, *task, "--episodes", OBSTACLE_DEMOS, "--seed",
                         obstacle_record_seed, "--out", results / "eval_demos.json")]

    def obstacle_model(name, k, policy, *model):
        results = exp / "obstacles" / name
        results.mkdir(parents=True, exist_ok=True)
        dataset = data / f"obstacles-{k}"
        return Job(f"obstacles-{name}", [
            [CIFLOW, "train", "--task", "obstacle-avoidance", "--demos", dataset, "--out",
             policy, *model],
            *obstacle_evaluations(policy, k, results),
            evaluate(policy, "--kwarg", f"obstacles={k}", "--field", results / "field.json",
                     "--field-demos", dataset),
        ], after=[f"record-obstacles-{k}"])

    for k in OBSTACLE_COUNTS:
        policy = policies / f"obstacles-{k}"
        # 3000 episodes through the Python recorder would take minutes of round trips;
        # `ciflow demos` runs the same expert in-process and writes the same dataset.
        jobs.append(Job(f"record-obstacles-{k}", [[
            CIFLOW, "demos", "--task", "obstacle-avoidance", "--kwarg", f"obstacles={k}",
            "--episodes", OBSTACLE_DEMOS, "--seed", obstacle_record_seed,
            "--out", data / f"obstacles-{k}",
            "--overwrite"]]))
        with_baseline = ["--baseline"] if k == max(OBSTACLE_COUNTS) else []
        jobs.append(obstacle_model(str(k), k, policy, *OBSTACLE_MODEL, *with_baseline))
        jobs.append(stability(f"obstacles-{k}-flow", policy, f"obstacles-{k}",
                              "--negative-control", *OBSTACLE_ROBOT_LOOP))
        jobs.append(obstacle_model(f"{k}-{OBSTACLE_GENERIC}", k,
                                   policies / f"obstacles-{k}-{OBSTACLE_GENERIC}",
                                   *OBSTACLE_GENERIC_MODEL))
    k = max(OBSTACLE_COUNTS)
    baseline, results = policies / f"obstacles-{k}" / "baseline", exp / "obstacles" / OBSTACLE_BASELINE
    results.mkdir(parents=True, exist_ok=True)
    # The unconstrained control on the flows' held-out episodes: what stability costs.
    jobs.append(Job(f"obstacles-{OBSTACLE_BASELINE}", obstacle_evaluations(baseline, k, results),
                    after=[f"obstacles-{k}"]))
    jobs.append(stability(f"obstacles-{k}-baseline", baseline, f"obstacles-{k}"))

    # Limit cycle: learning curves over the number of trajectories, held-out contexts, for
    # the paper's star-shaped phases and for the curled outlines (no longer star-shaped).
    for family, train_set, test_set, field_contexts in LIMIT_CYCLE_FAMILIES:
        lc_train, lc_test = data / family, data / f"{family}-heldout"
        results = exp / family.replace("-", "_")
        (results / "nll").mkdir(parents=True, exist_ok=True)
        jobs += [record(f"record-{family}", "limit-cycle", 10, 0, lc_train,
                        "--option", f"context_set={train_set}"),
                 record(f"record-{family}-heldout", "limit-cycle", 10, TEST_SEED, lc_test,
                        "--option", f"context_set={test_set}")]
        best_n = max(LIMIT_CYCLE_TRAJECTORIES)
        for n in LIMIT_CYCLE_TRAJECTORIES:
            for seed in SEEDS:
                policy, nll = policies / family / f"{n}_seed{seed}", results / "nll"
                # The model run closed loop trains the unconstrained MLP beside it.
                control = ["--baseline"] if (n, seed) == (best_n, 0) else []
                jobs.append(Job(f"{family}-{n}-seed{seed}", [
                    [CIFLOW, "train", "--task", "limit-cycle", "--demos", lc_train, "--subset",
                     n, "--seed", seed, "--out", policy, *LIMIT_CYCLE_MODEL, *control],
                    evaluate(policy, "--nll", lc_train, "--nll-subset", n, "--seed", seed,
                             "--out", nll / f"{n}_seed{seed}_train.json"),
                    evaluate(policy, "--nll", lc_test, "--out", nll / f"{n}_seed{seed}_test.json"),
                ], after=[f"record-{family}", f"record-{family}-heldout"]))
        best = policies / family / f"{best_n}_seed0"
        best_job = f"{family}-{best_n}-seed0"
        # Closed loop on the training and the held-out contexts: the flow, the MLP beside
        # it and the expert, from the same starts (README "The experiments").
        closed_loop = results / "closed_loop"
        closed_loop.mkdir(parents=True, exist_ok=True)
        actors = (("flow", ["--checkpoint", best]),
                  ("baseline", ["--checkpoint", best / "baseline"]),
                  ("expert", ["--expert", "--task", "limit-cycle"]))
        jobs.append(Job(f"{family}-closed-loop", [
            [CIFLOW, "evaluate", *actor, "--option", f"context_set={contexts}", "--episodes",
             LIMIT_CYCLE_EVALUATION_EPISODES, "--seed", TEST_SEED,
             "--out", closed_loop / f"{name}-{contexts_name}.json"]
            for contexts_name, contexts in (("training", train_set), ("held_out", test_set))
            for name, actor in actors], after=[best_job]))
        jobs.append(Job(f"{family}-field", [evaluate(
            best, "--field", results / "field.json", "--field-contexts", field_contexts,
            "--field-demos", lc_train)], after=[best_job]))
        jobs.append(stability(f"{family}-flow", best, best_job, "--negative-control"))

    return jobs


def needed(jobs: list[Job], prefixes: list[str]) -> list[Job]:
    """The jobs named with one of `prefixes`, and those they wait for, in plan order."""
    by_name = {job.name: job for job in jobs}
    keep = set()
    stack = [job.name for job in jobs if job.name.startswith(tuple(prefixes))]
    if not stack:
        raise SystemExit(f"demo: no job starts with {prefixes}; jobs: {sorted(by_name)}")
    while stack:
        name = stack.pop()
        if name not in keep:
            keep.add(name)
            stack.extend(by_name[name].after)
    return [job for job in jobs if job.name in keep]


def start_engine(out: pathlib.Path) -> subprocess.Popen:
    """`ciflow serve` on the zero-configuration endpoint; returns once it is ready."""
    log = out / "logs" / "engine.log"
    engine = subprocess.Popen([CIFLOW, "serve", "--name", "demo"], cwd=ROOT,
                              stdout=open(log, "w"), stderr=subprocess.STDOUT,
                              start_new_session=True)
    try:
        wait_for_line(log, "ready", engine, timeout=30)
    except RuntimeError as error:
        engine.terminate()
        raise SystemExit(f"demo: the engine did not start: {error}\n{log.read_text()[-2000:]}"
                         "\n(is another `ciflow serve` already on tcp/127.0.0.1:7447?)")
    return engine


def interrupt(signum, frame):
    raise KeyboardInterrupt


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="out", help="output folder (default: out)")
    parser.add_argument("--only", nargs="+", metavar="PREFIX",
                        help="run only the jobs whose names start with PREFIX (and the jobs "
                        "they need), keeping the other results")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 2,
                        help="jobs run at once (default: one per core)")
    args = parser.parse_args(argv)
    out = (ROOT / args.out).resolve()
    if not args.only:
        for stale in ("data", "policies", "experiments", "logs"):
            shutil.rmtree(out / stale, ignore_errors=True)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    jobs = plan(out)
    if args.only:
        jobs = needed(jobs, args.only)
    signal.signal(signal.SIGTERM, interrupt)
    start = time.monotonic()
    engine = start_engine(out)
    runner = Runner(out / "logs", max(args.jobs, 1))
    try:
        times, failures = runner.run(jobs)
    except KeyboardInterrupt:
        print("\ndemo: interrupted", file=sys.stderr)
        return 130
    finally:
        os.killpg(engine.pid, signal.SIGTERM)
        engine.wait()
    report = out / "report.md"
    subprocess.run([PYTHON, ROOT / "scripts" / "report.py", out / "experiments", report],
                   check=True)
    minutes = (time.monotonic() - start) / 60
    busiest = sorted(times.items(), key=lambda item: -item[1])[:5]
    print(f"\ndemo: done in {minutes:.1f} min (longest jobs: "
          + ", ".join(f"{name} {seconds:.0f} s" for name, seconds in busiest) + ")")
    print(f"demo: report {report}")
    for failure in failures:
        tail = failure.log.read_text()[-2000:] if failure.log.exists() else ""
        print(f"\ndemo: {failure}\n--- last lines of {failure.log} ---\n{tail}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
