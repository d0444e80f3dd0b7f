"""``python -m ciflow.perturb``: push a robot and change its context while a policy drives
it, and record what happens.

Either attach to a running session (``--session ID --token HEX``, e.g. one whose owner
called ``env.unwrapped.run_policy``), or let the script make its own session of
``--task``, reset it and start ``--policy``. Then it applies its script, in simulated
seconds since the reset:

* ``--push link=6,force=0:40:0,at=1.5,duration=0.2`` — a world-aligned force (N; optional
  ``torque=x:y:z`` N·m) at movable link ``link``; or
  ``--push joint=0:10,at=1.5,duration=0.2`` — generalized forces, one per joint.
  Pushes are scheduled at once, with their start time: the engine applies them exactly.
* ``--context-step at=3.0,value=0:-0.7:0.8:0.1`` — the context jumps to ``value`` and then
  holds;
* ``--context-ramp at=3.0,value=...,duration=1.0`` — the context moves linearly to
  ``value`` over ``duration`` and then holds.

**Why context changes must settle.** A conditioned stable flow is globally asymptotically
stable for each *fixed* context: for every ``c`` the flow ``f(·, c)`` maps a contracting
latent system onto a motion converging to its attractor. While ``c`` keeps moving, the
motion follows a moving attractor and no convergence is guaranteed (the paper's
condition: the context must converge to a final value; a time-varying context is covered
only once it settles). So the script offers only changes that settle — a step that then
holds, or a ramp ending on a final value — after which the robot is again on a motion
that converges for the final context.

Telemetry is recorded with ``--record traces.json`` and plotted with ``--plot
traces.png`` (state and command against simulated time, pushes and context changes
marked); ``--rrd run.rrd`` saves the run as a Rerun recording (the robot in 3-D, the
series and the events; ``python -m ciflow.view`` explains what it holds).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

import ciflow
from ciflow import connection
from ciflow.arguments import positive_seconds
from ciflow.registration import task_entry
from ciflow.remote import Attached


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(":") if x != ""]


def _fields(text: str) -> dict[str, str]:
    fields = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep:
            raise argparse.ArgumentTypeError(f"`{item}` in `{text}` is not KEY=VALUE")
        fields[key.strip()] = value.strip()
    return fields


def parse_push(text: str) -> dict:
    """``link=6,force=0:40:0[,torque=0:0:0],at=1.5,duration=0.2`` or
    ``joint=0:10,at=1.5,duration=0.2`` → a perturbation message."""
    fields = _fields(text)
    try:
        timing = {"start": float(fields.pop("at")), "duration": float(fields.pop("duration"))}
        if "joint" in fields:
            push = {"kind": "joint_torque", "torque": _floats(fields.pop("joint"))}
        else:
            push = {
                "kind": "link_wrench",
                "link": int(fields.pop("link")),
                "force": _floats(fields.pop("force", "0:0:0")),
                "torque": _floats(fields.pop("torque", "0:0:0")),
            }
    except (KeyError, ValueError) as error:
        raise argparse.ArgumentTypeError(f"bad --push `{text}`: {error}") from None
    if fields:
        raise argparse.ArgumentTypeError(f"unknown --push fields {sorted(fields)}")
    if not all(math.isfinite(t) for t in timing.values()):
        raise argparse.ArgumentTypeError(f"bad --push `{text}`: `at` and `duration` are "
                                         "finite seconds")
    return {**push, **timing}


def parse_context_change(text: str) -> dict:
    """``at=3.0,value=a:b:...[,duration=1.0]`` → ``{at, value, duration}``."""
    fields = _fields(text)
    try:
        change = {
            "at": float(fields.pop("at")),
            "value": _floats(fields.pop("value")),
            "duration": float(fields.pop("duration", "0")),
        }
    except (KeyError, ValueError) as error:
        raise argparse.ArgumentTypeError(f"bad context change `{text}`: {error}") from None
    if fields or not (math.isfinite(change["at"]) and change["duration"] >= 0
                      and math.isfinite(change["duration"])):
        raise argparse.ArgumentTypeError(
            f"bad context change `{text}`: `at` and `duration` (≥ 0) are finite seconds")
    return change


class ContextSchedule:
    """Context changes that settle: each moves from the context at its start to its
    final value (at once, or linearly over its duration) and then holds."""

    def __init__(self, changes: list[dict]):
        self.pending = sorted(changes, key=lambda c: c["at"])
        self.active = None  # (change, initial value)

    def due(self, time: float, context: np.ndarray) -> np.ndarray | None:
        """The context to send at simulated ``time``, or None."""
        if self.active is None and self.pending and time >= self.pending[0]["at"]:
            self.active = (self.pending.pop(0), context.copy())
        if self.active is None:
            return None
        change, start = self.active
        final = np.asarray(change["value"], dtype=float)
        fraction = 1.0 if change["duration"] == 0 else (time - change["at"]) / change["duration"]
        if fraction >= 1.0:
            self.active = None
            return final
        return start + fraction * (final - start)


def plot(samples: list[dict], events: list[dict], path: str) -> None:
    try:
        import matplotlib
    except ImportError as error:
        raise SystemExit("--plot needs matplotlib: pip install 'ciflow[plot]'") from error

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    time_s = np.array([s["time"] for s in samples])
    panels = [("state", "state"), ("command", "command (desired acceleration)"),
              ("context", "context")]
    figure, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(9, 8))
    for axis, (field, label) in zip(axes, panels):
        values = np.array([s[field] for s in samples])
        for i in range(values.shape[1]):
            axis.plot(time_s, values[:, i], label=f"{field}[{i}]")
        for event in events:
            axis.axvspan(event["start"], event["start"] + max(event["duration"], 0.01),
                         color="red" if event["kind"] == "push" else "blue", alpha=0.15)
        axis.set_ylabel(label)
        axis.legend(loc="upper right", fontsize="x-small", ncol=4)
    axes[-1].set_xlabel("simulated time (s)")
    figure.suptitle("policy under perturbation (red: push, blue: context change)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ciflow.perturb", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    target = parser.add_argument_group("session")
    target.add_argument("--session", help="attach to this session id")
    target.add_argument("--token", help="the session's token (hex)")
    target.add_argument("--engine-name", help="name of the engine holding --session")
    target.add_argument("--task", help="make a session of this task instead (name or "
                        "Gymnasium id)")
    target.add_argument("--kwarg", action="append", default=[], metavar="NAME=VALUE",
                        help="construction argument of --task (e.g. obstacles=1)")
    target.add_argument("--seed", type=int, default=0, help="reset seed of --task")
    target.add_argument("--policy", help="policy to start (required with --task)")
    target.add_argument("--speed", type=float, default=1.0,
                        help="1 = real time, 0 = as fast as possible")
    parser.add_argument("--engine", help="endpoint, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--zenoh-config", help="Zenoh JSON5 file (e.g. via a router)")
    parser.add_argument("--push", action="append", type=parse_push, default=[])
    parser.add_argument("--context-step", action="append", type=parse_context_change,
                        default=[])
    parser.add_argument("--context-ramp", action="append", type=parse_context_change,
                        default=[])
    parser.add_argument("--duration", type=positive_seconds,
                        help="stop after this many simulated seconds (default: episode end)")
    parser.add_argument("--record", help="write the telemetry to this JSON file")
    parser.add_argument("--plot", help="plot state/command/context to this PNG file")
    parser.add_argument("--rrd", help="save the run as a Rerun recording (ciflow[view])")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--wait", type=positive_seconds, default=10.0,
                        help="give up after this many seconds without telemetry")
    args = parser.parse_args(argv)
    for change in args.context_step:
        change["duration"] = 0.0
    if args.duration is not None:
        _check_within(parser, args, args.duration, "--duration")
    try:
        return _perturb(parser, args)
    except (ValueError, ciflow.CiflowError, ciflow.EngineUnreachable) as error:
        print(f"ciflow.perturb: error: {error}", file=sys.stderr)
        return 2


def _check_within(parser, args, end: float, what: str) -> None:
    """Refuses pushes and context changes that start at or after the run's end `end`
    (simulated seconds, set by `what`): they would never act."""
    for push in args.push:
        if push["start"] >= end:
            parser.error(f"a push at {push['start']} s starts at or after the run's end "
                         f"({end} s, {what}): it would never act")
    for change in args.context_step + args.context_ramp:
        if change["at"] >= end:
            parser.error(f"a context change at {change['at']} s starts at or after the run's "
                         f"end ({end} s, {what}): it would never act")


def _perturb(parser, args) -> int:
    env = None
    task, kwargs = None, {}
    if args.session:
        if not args.token:
            parser.error("--session needs --token")
        try:
            control = ciflow.attach(args.session, args.token, args.engine, args.engine_name,
                                    args.zenoh_config)
        except ValueError as error:
            parser.error(str(error))
    elif args.task and args.policy:
        import gymnasium as gym

        kwargs = {k: float(v) for k, v in (item.split("=", 1) for item in args.kwarg)}
        try:
            task, _name = task_entry(args.task)
        except ValueError as error:
            parser.error(str(error))
        env = gym.make(task, engine=args.engine, zenoh_config=args.zenoh_config, **kwargs)
        spec = env.unwrapped.task_spec
        if args.duration is None:
            _check_within(parser, args, spec["max_episode_steps"] * spec["control_dt"],
                          "the episode's length")
        env.reset(seed=args.seed)
        control = env.unwrapped.attach()
        print(f"session {env.unwrapped.session_id} token {env.unwrapped.token_hex} "
              f"engine {env.unwrapped.engine_name}", flush=True)
    else:
        parser.error("give --session/--token, or --task and --policy")

    feed = control.telemetry(timeout=args.wait)
    time.sleep(0.3)  # let the engine see the subscriber before the run starts
    events = []
    for push in args.push:
        control.perturb(push)
        events.append({"kind": "push", "start": push["start"], "duration": push["duration"]})
    # Tests and scripts may wait for this line before they start the run.
    print(f"scheduled {len(args.push)} push(es)", flush=True)
    if env is not None:
        # The engine stops the run itself: at speed 0 the run outpaces the telemetry, and a
        # stop sent when a sample reports the end would arrive seconds of simulation late.
        steps = None
        if args.duration is not None:
            steps = math.ceil(args.duration / env.unwrapped.task_spec["control_dt"] - 1e-9)
        control.run_policy(args.policy, speed=args.speed, steps=steps)
    schedule = ContextSchedule(args.context_step + args.context_ramp)
    events += [{"kind": "context", "start": c["at"], "duration": c["duration"]}
               for c in schedule.pending]

    progress = None
    if not args.quiet:
        from tqdm import tqdm

        total = args.duration
        if total is None and env is not None:
            spec = env.unwrapped.task_spec
            total = spec["max_episode_steps"] * spec["control_dt"]
        progress = tqdm(total=total, unit="sim s", desc="perturb",
                        bar_format="{l_bar}{bar}| {n:.2f}/{total_fmt} sim s")
    samples = []
    try:
        for sample in feed:
            # Samples of the client's own resets and steps before the run are not ours.
            if not samples and not sample["running"]:
                continue
            samples.append(sample)
            if progress is not None:
                progress.update(max(sample["time"] - progress.n, 0.0))
            context = schedule.due(sample["time"], sample["context"])
            if context is not None:
                control.set_context(context)
            if not sample["running"]:
                break
            if args.duration is not None and sample["time"] >= args.duration:
                control.stop()
                break
    finally:
        if progress is not None:
            progress.close()
        feed.close()
    if not samples:
        print("no telemetry arrived (is a policy running on that session?)", file=sys.stderr)
        return 1
    last = samples[-1]
    print(f"{len(samples)} samples, t = {last['time']:.2f} s, episode "
          f"{'ended' if last['episode_done'] else 'not ended'}, final state {last['state']}")

    status = 0
    if task is None and (args.record or args.rrd):
        # An attached session: its engine says what it is.
        first = samples[0]
        try:
            described = connection.client(args.engine, args.zenoh_config).describe(
                first["engine"], first["identity"], first["session"])
            task, kwargs = described["task"], described["kwargs"]
        except (ciflow.CiflowError, ciflow.EngineUnreachable) as error:
            print(f"the engine did not say what session {first['session']} is ({error}): "
                  "the record names no task", file=sys.stderr)
    if args.record:
        with open(args.record, "w") as file:
            json.dump({
                "task": task,
                "kwargs": kwargs,
                "events": events,
                "samples": [{k: (v.tolist() if isinstance(v, np.ndarray) else v)
                             for k, v in s.items()} for s in samples],
            }, file)
    if args.plot:
        plot(samples, events, args.plot)
    if args.rrd and task is None:
        print(f"--rrd {args.rrd} not written: the session's task is unknown", file=sys.stderr)
        status = 1
    elif args.rrd:
        from ciflow import view

        recording = view.open_recording("ciflow.perturb", save=args.rrd)
        view.record_run(recording, task, kwargs, samples, events)
        view.finish(recording)
    if env is None:
        control.close()
    else:
        env.close()
    return status


if __name__ == "__main__":
    sys.exit(main())
