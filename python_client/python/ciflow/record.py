"""``python -m ciflow.record``: the demonstration recorder of the separate-process loop.

Rolls out a task's expert through ``gymnasium.make`` and the environment's
``expert_action`` (episode ``i`` reset with seed ``seed + i``), writes the episodes as a
dataset in exactly the Minari layout ``ciflow demos`` writes (the same Rust writer, atomic),
and publishes each episode as it finishes on ``ciflow/v2/episodes/<task>/<recorder>``, where
``ciflow train --from-zenoh N`` collects them::

    python -m ciflow.record --task pouring --episodes 220 --seed 0 --out data/pouring
    python -m ciflow.record --task obstacle-avoidance --kwarg obstacles=1 --episodes 8 \\
        --out data/obstacles --engine tcp/10.0.0.5:7447

The engine is found as ``gymnasium.make`` finds it (``--engine``/``CIFLOW_ENGINE``,
``--zenoh-config``/``CIFLOW_ZENOH_CONFIG``, else the local one, embedded if none runs), and
episodes are published through that same Zenoh session.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from ciflow import _native, connection
from ciflow.convert import to_lerobot
from ciflow.registration import task_entry
from ciflow.spaces import construction_kwargs

__all__ = ["Recorded", "record", "main"]


@dataclass(frozen=True)
class Recorded:
    """What :func:`record` produced."""

    path: Path | None
    dataset_id: str
    episodes: int
    steps: int
    #: Key expression the episodes were published on (``None`` with ``publish=False``).
    key: str | None


def _task_numbers(task_id: str, values: dict | None, what: str) -> dict[str, float]:
    """Numbers of construction arguments or reset options: numbers as they are, names the
    task gives its values (e.g. LASA's ``shape="Sshape"``) as their index."""
    numbers = {}
    for key, value in (values or {}).items():
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise TypeError(f"{what} {key}={value!r}: expected a number or a name")
        numbers[key] = _native.task_value(task_id, key, str(value))
        if not np.isfinite(numbers[key]):
            raise ValueError(f"{what} {key}={value!r} is not finite")
    return numbers


def _default_recorder() -> str:
    return f"rec-{os.getpid()}-{os.urandom(3).hex()}"


def _rollout(env: gym.Env, seed: int, options: dict) -> dict:
    """One expert episode, recorded as ``ciflow_envs::rollout::expert_episode`` does."""
    observation, info = env.reset(seed=seed, options=options or None)
    observations, actions, rewards = [observation], [], []
    infos = {key: [float(value)] for key, value in info.items()}
    expert = env.unwrapped.expert_action
    while True:
        action = expert()
        observation, reward, terminated, truncated, info = env.step(action)
        actions.append(action)
        observations.append(observation)
        rewards.append(reward)
        for key, value in info.items():
            infos.setdefault(key, []).append(float(value))
        if terminated or truncated:
            break
    wire = lambda rows: np.ascontiguousarray(rows, dtype="<f8").tobytes()  # noqa: E731
    return {
        "observations": wire(observations),
        "actions": wire(actions),
        "rewards": wire(rewards),
        "terminated": bool(terminated),
        "truncated": bool(truncated),
        "infos": {key: wire(series) for key, series in infos.items()},
    }


def record(
    task: str,
    episodes: int,
    out: str | os.PathLike | None,
    *,
    seed: int = 0,
    kwargs: dict | None = None,
    options: dict | None = None,
    engine: str | None = None,
    zenoh_config: str | None = None,
    publish: bool = True,
    recorder: str | None = None,
    dataset_id: str | None = None,
    overwrite: bool = False,
    progress: bool = True,
    format: str = "minari",
) -> Recorded:
    """Records ``episodes`` expert episodes of ``task``.

    Arguments:
        task: Gymnasium id or command-line name (``pouring``, ``ciflow/Pouring-v0``).
        episodes: how many; episode ``i`` is reset with seed ``seed + i``.
        out: dataset directory to write (``None``: only publish).
        kwargs: the task's construction arguments (``{"obstacles": 3}``).
        options: reset options for every episode (``{"context_set": 2}``).
        engine, zenoh_config: which engine, as for ``gymnasium.make``.
        publish: publish each finished episode on ``ciflow/v2/episodes/<task>/<recorder>``.
        recorder: the ``<recorder>`` chunk (default: ``rec-<pid>-<random>``).
        dataset_id: Minari id (default ``ciflow/<task>-expert-v0``, as ``ciflow demos``).
        overwrite: replace an existing dataset at ``out``.
        progress: show a tqdm bar.
        format: ``"minari"`` (the layout ``ciflow train`` reads) or ``"lerobot"`` (v3.0,
            written from the Minari layout by ``ciflow.convert.to_lerobot``).
    """
    task_id, name = task_entry(task)
    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**64 - episodes:
        raise ValueError(f"seed must be an integer in [0, 2^64 - episodes), got {seed!r}")
    if out is None and not publish:
        raise ValueError("nothing to do: no output directory and publishing disabled")
    if format not in ("minari", "lerobot"):
        raise ValueError(f"format must be 'minari' or 'lerobot', got {format!r}")
    out = Path(out) if out is not None else None
    if out is not None:
        _native.check_replaceable(str(out), overwrite)
    kwargs = construction_kwargs(task_id, kwargs or {})
    options = _task_numbers(task_id, options, "reset option")
    _native.check_options_keep_kwargs(kwargs, options)
    if dataset_id is None:
        dataset_id = f"ciflow/{name}-expert-v0"

    env = gym.make(task_id, engine=engine, zenoh_config=zenoh_config, **kwargs)
    try:
        spec = _native.DatasetSpec(env.unwrapped.task_spec, dataset_id, kwargs=kwargs)
        # LeRobot is written from the Minari layout, recorded beside the target first.
        minari = out
        if out is not None and format == "lerobot":
            minari = out.with_name(f".{out.name}.minari-{os.getpid()}")
        writer = _native.DatasetWriter(str(minari), spec, True) if out is not None else None
        publisher = None
        if publish:
            # The client gymnasium.make resolved: the episodes leave through its session.
            client, _engine = connection.resolve(task_id, engine, zenoh_config)
            publisher = client.episode_publisher(name, recorder or _default_recorder())
        bar = _progress_bar(episodes, name) if progress else None
        steps = 0
        for index in range(episodes):
            episode = _native.Episode(spec, seed + index, **_rollout(env, seed + index, options))
            steps += len(episode)
            if writer is not None:
                writer.append(episode)
            if publisher is not None:
                publisher.publish(index, spec, episode)
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        path = Path(writer.finish()) if writer is not None else None
        if path is not None and format == "lerobot":
            try:
                path = to_lerobot(path, out, overwrite=overwrite)
            finally:
                shutil.rmtree(minari, ignore_errors=True)
    finally:
        env.close()
    return Recorded(
        path=path,
        dataset_id=dataset_id,
        episodes=episodes,
        steps=steps,
        key=publisher.key if publisher is not None else None,
    )


def _progress_bar(total: int, name: str):
    from tqdm import tqdm

    return tqdm(total=total, desc=f"{name} demos", unit="episode", file=sys.stderr)


def _pairs(texts: list[str] | None, flag: str) -> dict[str, str]:
    pairs = {}
    for text in texts or []:
        key, sep, value = text.partition("=")
        if not sep or not key:
            raise SystemExit(f"{flag} {text!r} is not NAME=VALUE")
        pairs[key] = value
    return pairs


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ciflow.record",
        description="Record expert demonstrations through gymnasium.make: write a Minari "
        "dataset (as `ciflow demos`) and publish each episode on "
        "ciflow/v2/episodes/<task>/<recorder> for `ciflow train --from-zenoh`.",
    )
    parser.add_argument("--task", required=True, help="task name or Gymnasium id")
    parser.add_argument("--episodes", type=int, default=100, help="number of episodes")
    parser.add_argument("--seed", type=int, default=0, help="episode i is reset with seed + i")
    parser.add_argument("--out", help="dataset directory to create (omit it to only publish)")
    parser.add_argument("--kwarg", action="append", metavar="NAME=VALUE",
                        help="construction argument of the task, e.g. obstacles=3 (repeatable)")
    parser.add_argument("--option", action="append", metavar="NAME=VALUE",
                        help="reset option for every episode, e.g. context_set=2 (repeatable)")
    parser.add_argument("--engine", help="engine endpoint (tcp/host:7447) or name "
                        "(default: CIFLOW_ENGINE, else the local engine)")
    parser.add_argument("--zenoh-config", help="standard Zenoh JSON5 file "
                        "(default: CIFLOW_ZENOH_CONFIG)")
    parser.add_argument("--recorder", help="recorder name in the episode key")
    parser.add_argument("--dataset-id", help="Minari id (default ciflow/<task>-expert-v0)")
    parser.add_argument("--no-publish", action="store_true",
                        help="only write the dataset, publish nothing")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--format", choices=("minari", "lerobot"), default="minari",
                        help="layout of --out: Minari's (what `ciflow train` reads) or "
                        "LeRobot v3.0")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.out is None and args.no_publish:
        parser.error("--out is required with --no-publish")
    try:
        result = record(
            args.task,
            args.episodes,
            args.out,
            seed=args.seed,
            kwargs=_pairs(args.kwarg, "--kwarg"),
            options=_pairs(args.option, "--option"),
            engine=args.engine,
            zenoh_config=args.zenoh_config,
            publish=not args.no_publish,
            recorder=args.recorder,
            dataset_id=args.dataset_id,
            overwrite=args.overwrite,
            progress=not args.quiet,
            format=args.format,
        )
    except (ValueError, TypeError, FileExistsError, _native.EngineUnreachable,
            _native.CiflowError) as error:
        print(f"ciflow.record: error: {error}", file=sys.stderr)
        return 2
    where = f"wrote {result.path}" if result.path else "wrote no dataset"
    published = f", published on {result.key}" if result.key else ""
    print(f"{where} ({result.dataset_id}): {result.episodes} episodes, "
          f"{result.steps} steps{published}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
