"""Demonstrations recorded elsewhere, in the layout ``ciflow train`` reads.

A Minari dataset made by any tool — either storage (HDF5, Minari's default, or Arrow),
``Box`` or ``Dict`` spaces — is read with Minari's own loader; flags name which of its
fields are the policy's state ``y`` and its context ``c``::

    python -m ciflow.convert SRC OUT --state observations/achieved_goal \\
        --context observations/desired_goal --dt 0.01

``ciflow train --state ... --context ... --dt ...`` runs this itself. A field is a path
through the episode's arrays — ``observations``, ``actions``, ``rewards`` or
``infos``, then ``/key`` per ``Dict`` level — with an optional column range
``[start:stop]`` or index ``[i]``: ``observations[0:2]``, ``infos/goal``.

What is written (``envs/DATASET.md``): observations ``[y, ẏ, c]`` with ``ẏ`` the forward
difference ``(y[t+1] - y[t]) / dt`` (the last row repeats the one before; the trainer
reads only ``y`` and ``c``), the source's actions and rewards, and no infos: no episode is
dropped as failed and no step as pushed.

Checked, each with an error naming the episode and field: the fields exist and hold
numbers; state and context have one row per observation; every value is finite; the time
step is given once (``--dt``, or a ciflow dataset's own ``control_dt``) and, when both,
the two agree.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ciflow import _native

#: The episode's top-level arrays a field may start from.
ROOTS = ("observations", "actions", "rewards", "infos")
_FIELD = re.compile(
    r"^(?P<path>[^\[\]]+?)(?:\[(?:(?P<start>-?\d*):(?P<stop>-?\d*)|(?P<index>-?\d+))\])?$"
)


class ConversionError(ValueError):
    """The source cannot be converted as asked; the message says what and where."""


@dataclass(frozen=True)
class Field:
    """A slice of columns of one array of an episode."""

    text: str
    path: tuple[str, ...]
    columns: slice

    @staticmethod
    def parse(text: str) -> Field:
        match = _FIELD.match(text.strip())
        if match is None:
            raise ConversionError(f"field {text!r} is not PATH, PATH[start:stop] or PATH[i]")
        path = tuple(match["path"].split("/"))
        if path[0] not in ROOTS or not all(path):
            raise ConversionError(
                f"field {text!r} must start with one of {', '.join(ROOTS)}, levels "
                "separated by /"
            )
        if match["index"] is not None:
            index = int(match["index"])
            columns = slice(index, index + 1 if index != -1 else None)
        else:
            number = lambda s: int(s) if s else None  # noqa: E731
            columns = slice(number(match["start"]), number(match["stop"]))
        return Field(text, path, columns)

    def rows(self, episode, number: int) -> np.ndarray:
        """The field's values in `episode` (number `number`), one row per time step."""
        value = getattr(episode, self.path[0])
        for depth, key in enumerate(self.path[1:], start=2):
            if not isinstance(value, dict) or key not in value:
                have = ", ".join(sorted(value)) if isinstance(value, dict) else "not a Dict"
                raise ConversionError(
                    f"episode {number}: field {self.text!r}: no {'/'.join(self.path[:depth])!r} "
                    f"(there: {have})"
                )
            value = value[key]
        if isinstance(value, dict):
            raise ConversionError(
                f"field {self.text!r} is a Dict with {', '.join(sorted(value))}: name one "
                "of them after a /"
            )
        array = np.asarray(value)
        if not np.issubdtype(array.dtype, np.number) and array.dtype != bool:
            raise ConversionError(
                f"episode {number}: field {self.text!r} holds {array.dtype}, not numbers"
            )
        array = array.astype(np.float64).reshape(len(array), -1)
        selected = array[:, self.columns]
        if selected.shape[1] == 0:
            raise ConversionError(
                f"field {self.text!r} selects no column of {'/'.join(self.path)}'s "
                f"{array.shape[1]}"
            )
        return selected


def time_step(dataset, dt: float | None) -> float:
    """`dt` or the dataset's own ``control_dt``: given once, or both agreeing."""
    recorded = dataset.storage.metadata.get("ciflow", {}).get("control_dt")
    if dt is None and recorded is None:
        raise ConversionError(
            "the dataset records no time step between observations: give it with --dt SECONDS"
        )
    if dt is not None and not (math.isfinite(dt) and dt > 0):
        raise ConversionError(f"--dt {dt} is not a positive number of seconds")
    if dt is not None and recorded is not None and not math.isclose(dt, recorded, rel_tol=1e-9):
        raise ConversionError(
            f"--dt {dt} s disagrees with the dataset's control_dt {recorded} s (a unit "
            "mismatch? leave --dt out to use the dataset's)"
        )
    return float(dt if dt is not None else recorded)


def convert(
    source: str | Path,
    out: str | Path,
    state: str,
    context: str | None = None,
    dt: float | None = None,
    overwrite: bool = False,
) -> Path:
    """Writes the demonstrations of the Minari dataset at `source` (its ``data``
    directory or the one above it) to `out`; returns `out`."""
    import minari

    source = Path(source)
    data = source / "data" if (source / "data" / "metadata.json").exists() else source
    if not (data / "metadata.json").exists():
        raise ConversionError(f"{source}: no Minari dataset (no metadata.json in it or in data/)")
    dataset = minari.MinariDataset(str(data))
    dt = time_step(dataset, dt)
    state_field = Field.parse(state)
    context_field = Field.parse(context) if context else None

    episodes = []
    for number, episode in enumerate(dataset.iterate_episodes()):
        y = state_field.rows(episode, number)
        c = context_field.rows(episode, number) if context_field else np.zeros((len(y), 0))
        steps = len(y) - 1
        if steps < 1:
            raise ConversionError(f"episode {number}: {len(y)} observation(s), no step")
        if len(c) != len(y):
            raise ConversionError(
                f"episode {number}: context {context!r} has {len(c)} rows, the state "
                f"{state!r} {len(y)} (the context needs one row per observation)"
            )
        actions = np.asarray(episode.actions, dtype=np.float64).reshape(steps, -1)
        rewards = np.asarray(episode.rewards, dtype=np.float64).reshape(steps)
        checked = (("state", y), ("context", c), ("actions", actions), ("rewards", rewards))
        for name, values in checked:
            bad = np.argwhere(~np.isfinite(values))
            if len(bad):
                raise ConversionError(
                    f"episode {number}: {name} is NaN or infinite at step {bad[0][0]}"
                )
        velocity = np.diff(y, axis=0) / dt
        velocity = np.vstack([velocity, velocity[-1:]])
        episodes.append((episode, np.hstack([y, velocity, c]), actions, rewards))
    if not episodes:
        raise ConversionError(f"{source}: the dataset has no episode")
    spec = _native.DatasetSpec(
        {
            "id": source_id(dataset),
            "control_dt": dt,
            "observation_space": _bounds([e[1] for e in episodes], y.shape[1], c.shape[1]),
            "action_space": _unbounded(episodes[0][2].shape[1]),
            "context_space": _data_box([e[1][:, 2 * y.shape[1]:] for e in episodes]),
        },
        dataset.spec.dataset_id,
        algorithm_name=dataset.storage.metadata.get("algorithm_name") or "unknown",
    )
    writer = _native.DatasetWriter(str(out), spec, overwrite)
    wire = lambda rows: np.ascontiguousarray(rows, dtype="<f8").tobytes()  # noqa: E731
    for episode, observations, actions, rewards in episodes:
        seed = getattr(episode, "seed", None)
        writer.append(_native.Episode(
            spec, None if seed is None or seed < 0 else int(seed), wire(observations),
            wire(actions), wire(rewards), bool(episode.terminations[-1]),
            bool(episode.truncations[-1]),
        ))
    return Path(writer.finish())


def source_id(dataset) -> str:
    """The Gymnasium id of the environment that recorded `dataset`, if it says."""
    env_spec = dataset.spec.env_spec
    return env_spec.id if env_spec is not None else "unknown"


def _data_box(blocks: list[np.ndarray]) -> dict:
    values = np.vstack(blocks)
    low, high = values.min(axis=0).tolist(), values.max(axis=0).tolist()
    return {"low": low, "high": high, "dtype": "float64"}


def _unbounded(dim: int) -> dict:
    return {"low": [-math.inf] * dim, "high": [math.inf] * dim, "dtype": "float64"}


def _bounds(observations: list[np.ndarray], state_dim: int, context_dim: int) -> dict:
    """The data's box for `y` and `c`, unbounded for the difference `ẏ`."""
    box = _data_box(observations)
    for i in range(state_dim, 2 * state_dim):
        box["low"][i], box["high"][i] = -math.inf, math.inf
    return box


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ciflow.convert",
        description="Convert a Minari dataset made by any tool into the layout `ciflow train` "
        "reads, naming the fields that are the state and the context.",
    )
    parser.add_argument("source", help="Minari dataset directory (or its data/ directory)")
    parser.add_argument("out", help="dataset directory to create")
    parser.add_argument("--state", required=True, metavar="FIELD",
                        help="the policy's state, e.g. observations[0:2] or "
                        "observations/achieved_goal")
    parser.add_argument("--context", metavar="FIELD",
                        help="the policy's context, one row per observation, e.g. infos/goal")
    parser.add_argument("--dt", type=float, metavar="SECONDS",
                        help="seconds between observations (when the dataset does not record it)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    args = parser.parse_args(argv)
    try:
        path = convert(args.source, args.out, args.state, args.context, args.dt, args.overwrite)
    except (ConversionError, OSError, ValueError) as error:
        print(f"ciflow.convert: {error}", file=sys.stderr)
        return 2
    print(json.dumps({"out": str(path)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
