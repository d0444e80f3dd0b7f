"""Demonstrations recorded elsewhere, in the layout ``ciflow train`` reads.

Two formats, each read with its own maintained library, with flags naming which fields
are the policy's state ``y`` and its context ``c``:

* a **Minari** dataset made by any tool — either storage (HDF5, Minari's default, or
  Arrow), ``Box`` or ``Dict`` spaces — through Minari's loader; fields are paths from
  ``observations``, ``actions``, ``rewards`` or ``infos``, then ``/key`` per ``Dict`` level;
* a **LeRobot** dataset (v3.0: ``meta/info.json``, episodes concatenated in
  ``data/chunk-*/file-*.parquet``; v2.x: a parquet file per episode) through pyarrow;
  fields are its features, e.g. ``observation.state``; the time step is ``1 / fps``.

::

    python -m ciflow.convert SRC OUT --state observations/achieved_goal \
        --context observations/desired_goal --dt 0.01
    python -m ciflow.convert lerobot_dir OUT --state "observation.state[0:7]"

``ciflow train --state ... --context ... --dt ...`` runs this itself. A field takes an
optional column range ``[start:stop]`` or index ``[i]``: ``observations[0:2]``.

What is written (``envs/DATASET.md``): observations ``[y, ẏ, c]`` with ``ẏ`` the forward
difference ``(y[t+1] - y[t]) / dt`` (the last row repeats the one before; the trainer
reads only ``y`` and ``c``), the source's actions and rewards, and no infos: no episode is
dropped as failed and no step as pushed.

Checked, each with an error naming the episode and field: the fields exist and hold
numbers; state and context have one row per observation; every value is finite; the time
step is given once (``--dt``, or the dataset's own: a ciflow dataset's ``control_dt``,
LeRobot's ``fps``) and, when both, the two agree.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ciflow import _native

_FIELD = re.compile(
    r"^(?P<path>[^\[\]]+?)(?:\[(?:(?P<start>-?\d*):(?P<stop>-?\d*)|(?P<index>-?\d+))\])?$"
)


class ConversionError(ValueError):
    """The source cannot be converted as asked; the message says what and where."""


@dataclass(frozen=True)
class SourceEpisode:
    """One episode of a source: its named arrays (``Dict`` levels as dicts), with as many
    rows as it has observations, or one fewer for per-step arrays."""

    arrays: dict
    actions: np.ndarray
    rewards: np.ndarray
    terminated: bool
    truncated: bool
    seed: int | None = None


@dataclass(frozen=True)
class Source:
    """A dataset made elsewhere, read with its format's own library."""

    kind: str
    dataset_id: str
    env_id: str
    algorithm_name: str
    #: Seconds between observations, when the dataset records it.
    dt: float | None
    episodes: Callable[[], Iterator[SourceEpisode]]


@dataclass(frozen=True)
class Field:
    """A slice of columns of one array of an episode."""

    text: str
    path: tuple[str, ...]
    columns: slice

    @staticmethod
    def parse(text: str) -> Field:
        match = _FIELD.match(text.strip())
        path = tuple(match["path"].split("/")) if match else ()
        if match is None or not all(path):
            raise ConversionError(
                f"field {text!r} is not PATH, PATH[start:stop] or PATH[i], with Dict levels "
                "separated by /"
            )
        if match["index"] is not None:
            index = int(match["index"])
            columns = slice(index, index + 1 if index != -1 else None)
        else:
            number = lambda s: int(s) if s else None  # noqa: E731
            columns = slice(number(match["start"]), number(match["stop"]))
        return Field(text, path, columns)

    def rows(self, episode: SourceEpisode, number: int) -> np.ndarray:
        """The field's values in `episode` (number `number`), one row per time step."""
        value = episode.arrays
        for depth, key in enumerate(self.path, start=1):
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
        width = array.shape[1]
        if any(b is not None and not -width <= b <= width
               for b in (self.columns.start, self.columns.stop)):
            # numpy would quietly keep the columns there are.
            raise ConversionError(
                f"field {self.text!r} reaches past the {width} columns of "
                f"{'/'.join(self.path)}"
            )
        selected = array[:, self.columns]
        if selected.shape[1] == 0:
            raise ConversionError(
                f"field {self.text!r} selects no column of {'/'.join(self.path)}'s "
                f"{array.shape[1]}"
            )
        return selected


def _check_apart(source: str | Path, out: str | Path) -> None:
    """Refuses an `out` that is `source` or holds it: replacing it would delete the
    source. (One inside the source only adds a directory to it; the replace check keeps
    it from taking the place of the source's own files.)"""
    source, out = Path(source).resolve(), Path(out).resolve()
    if source == out or out in source.parents:
        raise ConversionError(f"{out} is or holds the source {source}: write the converted "
                              "dataset somewhere else")


def open_source(path: str | Path) -> Source:
    """The dataset at `path`: LeRobot (``meta/info.json``) or Minari (``metadata.json`` in
    it or in its ``data/``)."""
    path = Path(path)
    if (path / "meta" / "info.json").exists():
        return _lerobot(path)
    data = path / "data" if (path / "data" / "metadata.json").exists() else path
    if (data / "metadata.json").exists():
        return _minari(data)
    raise ConversionError(
        f"{path}: neither a Minari dataset (metadata.json in it or in data/) nor a LeRobot "
        "one (meta/info.json)"
    )


def _minari(data: Path) -> Source:
    import minari

    dataset = minari.MinariDataset(str(data))
    metadata = dataset.storage.metadata

    def episodes():
        for episode in dataset.iterate_episodes():
            steps = len(episode.rewards)
            yield SourceEpisode(
                arrays={
                    "observations": episode.observations, "actions": episode.actions,
                    "rewards": episode.rewards, "infos": episode.infos,
                },
                actions=np.asarray(episode.actions, dtype=np.float64).reshape(steps, -1),
                rewards=np.asarray(episode.rewards, dtype=np.float64).reshape(steps),
                terminated=bool(episode.terminations[-1]),
                truncated=bool(episode.truncations[-1]),
                seed=getattr(episode, "seed", None),
            )

    env_spec = dataset.spec.env_spec
    return Source(
        kind="Minari", dataset_id=dataset.spec.dataset_id,
        env_id=env_spec.id if env_spec is not None else "unknown",
        algorithm_name=metadata.get("algorithm_name") or "unknown",
        dt=metadata.get("ciflow", {}).get("control_dt"), episodes=episodes,
    )


def _lerobot(root: Path) -> Source:
    """A LeRobot dataset, v3.0 (episodes concatenated in ``data/chunk-*/file-*.parquet``)
    or v2.x (one parquet file per episode), read with pyarrow. Each frame is an
    observation; its ``action`` led to the next frame, so the last frame's action has no
    step and is left out (likewise ``next.reward``)."""
    import pyarrow.parquet as pq

    info = json.loads((root / "meta" / "info.json").read_text())
    version = str(info.get("codebase_version", ""))
    if not version.startswith(("v2", "v3")):
        raise ConversionError(f"{root}: LeRobot codebase_version {version!r}: v2.x or v3.0 only")
    files = sorted((root / "data").glob("**/*.parquet"))
    if not files:
        raise ConversionError(f"{root}: no parquet file under data/")
    table = pq.read_table(files[0]) if len(files) == 1 else _concat(pq, files)
    for column in ("episode_index", "frame_index"):
        if column not in table.column_names:
            raise ConversionError(f"{root}: the data have no {column!r} column")
    numeric = [name for name, feature in info.get("features", {}).items()
               if feature.get("dtype") not in ("video", "image", "string")
               and name in table.column_names]
    episode_index = table.column("episode_index").to_numpy()
    frame_index = table.column("frame_index").to_numpy()

    def where(row: int) -> str:
        return f"episode {episode_index[row]}, frame {frame_index[row]}"

    columns = {name: _column(table, name, where) for name in numeric}

    def episodes():
        for episode in np.unique(episode_index):
            rows = np.flatnonzero(episode_index == episode)
            rows = rows[np.argsort(frame_index[rows], kind="stable")]
            arrays = {name: values[rows] for name, values in columns.items()}
            steps = len(rows) - 1
            if steps < 1:
                raise ConversionError(f"episode {episode}: {len(rows)} frame(s), no step")

            def per_step(name: str) -> np.ndarray:
                return arrays[name][:-1] if name in arrays else np.zeros((steps, 0))

            done = arrays.get("next.done")
            yield SourceEpisode(
                arrays=arrays,
                actions=per_step("action").reshape(steps, -1),
                rewards=per_step("next.reward").reshape(steps, -1).sum(axis=1),
                terminated=bool(done[-1]) if done is not None else False,
                truncated=done is None,
            )

    fps = info.get("fps")
    return Source(
        kind=f"LeRobot {version}", dataset_id=_minari_id(root.name),
        env_id=info.get("robot_type") or "unknown", algorithm_name="unknown",
        dt=1.0 / fps if fps else None, episodes=episodes,
    )


def _minari_id(name: str) -> str:
    """The Minari id of a LeRobot dataset's directory `name`: ``lerobot/<name>-v0`` (its
    version kept if it ends in one), characters an id cannot hold as ``_``. The directory
    name alone (``pusht``) is not an id Minari opens."""
    clean = re.sub(r"[^\w-]", "_", name).strip("-") or "dataset"
    return f"lerobot/{clean}" if re.search(r".-v\d+$", clean) else f"lerobot/{clean}-v0"


def _concat(pq, files):
    import pyarrow as pa

    return pa.concat_tables([pq.read_table(f) for f in files])


def _column(table, name: str, where) -> np.ndarray:
    """A numeric column as a 2-D float64 array (lists of numbers become rows, which must
    all be there and all be as long; `where(row)` names a row in errors)."""
    import pyarrow as pa

    column = table.column(name).combine_chunks()
    if pa.types.is_list(column.type) or pa.types.is_fixed_size_list(column.type):
        missing = np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))
        if len(missing):
            raise ConversionError(
                f"{name!r} has no value at {where(missing[0])} ({len(missing)} row(s) empty)")
        lengths = (column.value_lengths().to_numpy(zero_copy_only=False)
                   if pa.types.is_list(column.type)
                   else np.full(len(column), column.type.list_size))
        width = int(lengths[0]) if len(lengths) else 0
        ragged = np.flatnonzero(lengths != width)
        if len(ragged):
            raise ConversionError(
                f"{name!r} holds {lengths[ragged[0]]} value(s) at {where(ragged[0])} but "
                f"{width} at {where(0)}: every frame needs as many")
        values = column.flatten().to_numpy(zero_copy_only=False)
        return values.astype(np.float64).reshape(len(column), width)
    return column.to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(column), 1)


def time_step(source: Source, dt: float | None) -> float:
    """`dt` or the dataset's own time step: given once, or both agreeing."""
    recorded = source.dt
    if dt is None and recorded is None:
        raise ConversionError(
            "the dataset records no time step between observations: give it with --dt SECONDS"
        )
    if dt is not None and not (math.isfinite(dt) and dt > 0):
        raise ConversionError(f"--dt {dt} is not a positive number of seconds")
    if dt is not None and recorded is not None and not math.isclose(dt, recorded, rel_tol=1e-9):
        raise ConversionError(
            f"--dt {dt} s disagrees with the dataset's own time step, {recorded} s (a unit "
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
    velocity: str | None = None,
) -> Path:
    """Writes the demonstrations of the dataset at `source` (Minari: the dataset or its
    ``data`` directory; LeRobot: the directory holding ``meta/``) to `out`; returns
    `out`. `velocity` names the state's own rates where the data have them (else the
    forward difference stands in)."""
    _check_apart(source, out)
    dataset = open_source(source)
    dt = time_step(dataset, dt)
    state_field = Field.parse(state)
    context_field = Field.parse(context) if context else None
    velocity_field = Field.parse(velocity) if velocity else None

    episodes = []
    for number, episode in enumerate(dataset.episodes()):
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
        checked = (
            ("state", y), ("context", c), ("actions", episode.actions),
            ("rewards", episode.rewards),
        )
        for name, values in checked:
            bad = np.argwhere(~np.isfinite(values))
            if len(bad):
                raise ConversionError(
                    f"episode {number}: {name} is NaN or infinite at step {bad[0][0]}"
                )
        if velocity_field is not None:
            rates = velocity_field.rows(episode, number)
            if rates.shape != y.shape:
                raise ConversionError(
                    f"episode {number}: velocity {velocity!r} is {rates.shape[0]} × "
                    f"{rates.shape[1]}, the state {y.shape[0]} × {y.shape[1]}"
                )
        else:
            rates = np.diff(y, axis=0) / dt
            rates = np.vstack([rates, rates[-1:]])
        episodes.append((episode, np.hstack([y, rates, c])))
    if not episodes:
        raise ConversionError(f"{source}: the dataset has no episode")
    spec = _native.DatasetSpec(
        {
            "id": dataset.env_id,
            "control_dt": dt,
            "observation_space": _bounds([e[1] for e in episodes], y.shape[1], c.shape[1]),
            "action_space": _unbounded(episodes[0][0].actions.shape[1]),
            "context_space": _data_box([e[1][:, 2 * y.shape[1]:] for e in episodes]),
        },
        dataset.dataset_id,
        algorithm_name=dataset.algorithm_name,
    )
    writer = _native.DatasetWriter(str(out), spec, overwrite)
    wire = lambda rows: np.ascontiguousarray(rows, dtype="<f8").tobytes()  # noqa: E731
    for episode, observations in episodes:
        seed = None if episode.seed is None or episode.seed < 0 else int(episode.seed)
        writer.append(_native.Episode(
            spec, seed, wire(observations), wire(episode.actions), wire(episode.rewards),
            episode.terminated, episode.truncated,
        ))
    return Path(writer.finish())


def to_lerobot(source: str | Path, out: str | Path, task: str | None = None,
               overwrite: bool = False) -> Path:
    """Writes the ciflow dataset at `source` as a LeRobot v3.0 dataset at `out` (one data
    file, one episodes file; numbers as float32, as LeRobot stores them): per frame
    ``observation.state`` = the position ``q``, ``observation.velocity`` = ``q̇``,
    ``observation.environment_state`` = the context (left out without one), ``action``
    (the last frame's, which no step follows, is zero), ``next.reward`` and
    ``next.done``. Returns `out`."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    _check_apart(source, out)
    spec, episodes = _native.read_dataset(str(source))
    out = Path(out)
    _native.check_replaceable(str(out), overwrite)
    fps = 1.0 / spec["control_dt"]
    if not math.isclose(fps, round(fps), rel_tol=1e-9):
        raise ConversionError(f"LeRobot needs a whole number of frames per second, not {fps}")
    fps = round(fps)
    observation_dim = len(spec["observation_space"]["low"])
    context_dim = len(spec["context_space"]["low"])
    action_dim = len(spec["action_space"]["low"])
    position_dim = (observation_dim - context_dim) // 2
    task = task or f"{spec['env_id']} ({spec['algorithm_name']} demonstrations)"

    columns = {name: [] for name in (
        "observation.state", "observation.velocity", "observation.environment_state",
        "action", "next.reward", "next.done", "timestamp", "frame_index", "episode_index",
        "index", "task_index")}
    lengths = []
    for number, episode in enumerate(episodes):
        observations = np.frombuffer(episode["observations"], "<f8").reshape(-1, observation_dim)
        frames = len(observations)
        actions = np.frombuffer(episode["actions"], "<f8").reshape(-1, action_dim)
        rewards = np.frombuffer(episode["rewards"], "<f8")
        done = bool(np.frombuffer(episode["terminations"], np.uint8)[-1])
        columns["observation.state"] += list(observations[:, :position_dim])
        columns["observation.velocity"] += list(observations[:, position_dim:2 * position_dim])
        columns["observation.environment_state"] += list(observations[:, 2 * position_dim:])
        columns["action"] += list(np.vstack([actions, np.zeros((1, action_dim))]))
        columns["next.reward"] += [*rewards, 0.0]
        columns["next.done"] += [False] * (frames - 1) + [done]
        columns["timestamp"] += list(np.arange(frames) / fps)
        columns["frame_index"] += list(range(frames))
        columns["episode_index"] += [number] * frames
        columns["index"] += list(range(sum(lengths), sum(lengths) + frames))
        columns["task_index"] += [0] * frames
        lengths.append(frames)

    vector = lambda name, dim: pa.FixedSizeListArray.from_arrays(  # noqa: E731
        pa.array(np.asarray(columns[name], dtype=np.float32).reshape(-1), pa.float32()), dim)
    dims = {"observation.state": position_dim, "observation.velocity": position_dim,
            "observation.environment_state": context_dim, "action": action_dim}
    if context_dim == 0:
        # A context-free task (LASA, a converted dataset without --context): LeRobot has
        # no zero-width feature, so the frames carry no environment state.
        del dims["observation.environment_state"]
    arrays = {name: vector(name, dim) for name, dim in dims.items()}
    arrays["next.reward"] = pa.array(columns["next.reward"], pa.float32())
    arrays["next.done"] = pa.array(columns["next.done"], pa.bool_())
    arrays["timestamp"] = pa.array(columns["timestamp"], pa.float32())
    for name in ("frame_index", "episode_index", "index", "task_index"):
        arrays[name] = pa.array(columns[name], pa.int64())

    staging = out.with_name(f".{out.name}.partial-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "data" / "chunk-000").mkdir(parents=True)
    (staging / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
    pq.write_table(pa.table(arrays), staging / "data" / "chunk-000" / "file-000.parquet")
    starts = np.cumsum([0, *lengths])
    pq.write_table(pa.table({
        "episode_index": pa.array(range(len(lengths)), pa.int64()),
        "tasks": pa.array([[task]] * len(lengths), pa.list_(pa.string())),
        "length": pa.array(lengths, pa.int64()),
        "data/chunk_index": pa.array([0] * len(lengths), pa.int64()),
        "data/file_index": pa.array([0] * len(lengths), pa.int64()),
        "dataset_from_index": pa.array(starts[:-1], pa.int64()),
        "dataset_to_index": pa.array(starts[1:], pa.int64()),
        "meta/episodes/chunk_index": pa.array([0] * len(lengths), pa.int64()),
        "meta/episodes/file_index": pa.array([0] * len(lengths), pa.int64()),
    }), staging / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    # pandas reads this file with the task text as the index, as LeRobot expects.
    tasks = pa.table({"task_index": pa.array([0], pa.int64()),
                      "__index_level_0__": pa.array([task], pa.large_string())})
    pandas_index = {"index_columns": ["__index_level_0__"], "column_indexes": [], "columns": [
        {"name": "task_index", "field_name": "task_index", "pandas_type": "int64",
         "numpy_type": "int64", "metadata": None},
        {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode",
         "numpy_type": "object", "metadata": None}]}
    tasks = tasks.replace_schema_metadata({"pandas": json.dumps(pandas_index)})
    pq.write_table(tasks, staging / "meta" / "tasks.parquet")

    features = {name: {"dtype": "float32", "shape": [dim], "names": None}
                for name, dim in dims.items()}
    features["next.reward"] = {"dtype": "float32", "shape": [1], "names": None}
    features["next.done"] = {"dtype": "bool", "shape": [1], "names": None}
    features["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
    for name in ("frame_index", "episode_index", "index", "task_index"):
        features[name] = {"dtype": "int64", "shape": [1], "names": None}
    info = {
        "codebase_version": "v3.0", "robot_type": spec["env_id"],
        "total_episodes": len(lengths), "total_frames": int(starts[-1]), "total_tasks": 1,
        "chunks_size": 1000, "data_files_size_in_mb": 100, "video_files_size_in_mb": 200,
        "fps": fps, "splits": {"train": f"0:{len(lengths)}"},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": None, "features": features,
    }
    (staging / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    stats = {}
    for name, array in arrays.items():
        values = np.asarray(array.flatten() if name in dims else array, dtype=np.float64)
        values = values.reshape(len(columns["index"]), -1)
        stats[name] = {"min": values.min(0).tolist(), "max": values.max(0).tolist(),
                       "mean": values.mean(0).tolist(), "std": values.std(0).tolist(),
                       "count": [len(values)]}
    (staging / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))
    if out.exists():
        shutil.rmtree(out)
    staging.rename(out)
    return out


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
        description="Convert a Minari or LeRobot dataset made by any tool into the layout "
        "`ciflow train` reads, naming the fields that are the state and the context; or, "
        "with --to-lerobot, a ciflow dataset into a LeRobot v3.0 one.",
    )
    parser.add_argument("source", help="the dataset directory")
    parser.add_argument("out", help="dataset directory to create")
    parser.add_argument("--state", metavar="FIELD",
                        help="the policy's state, e.g. observations[0:2] or "
                        "observations/achieved_goal or observation.state")
    parser.add_argument("--velocity", metavar="FIELD",
                        help="the state's rates, where the data have them (default: the "
                        "forward difference of the state)")
    parser.add_argument("--context", metavar="FIELD",
                        help="the policy's context, one row per observation, e.g. infos/goal")
    parser.add_argument("--dt", type=float, metavar="SECONDS",
                        help="seconds between observations (when the dataset does not record it)")
    parser.add_argument("--to-lerobot", action="store_true",
                        help="write the ciflow dataset SOURCE as a LeRobot v3.0 dataset")
    parser.add_argument("--task", help="with --to-lerobot: the task text of every episode")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing OUT")
    args = parser.parse_args(argv)
    if args.to_lerobot == (args.state is not None):
        parser.error("give either --state FIELD (to ciflow) or --to-lerobot")
    try:
        if args.to_lerobot:
            path = to_lerobot(args.source, args.out, args.task, args.overwrite)
        else:
            path = convert(args.source, args.out, args.state, args.context, args.dt,
                           args.overwrite, args.velocity)
    except (ConversionError, OSError, ValueError) as error:
        print(f"ciflow.convert: {error}", file=sys.stderr)
        return 2
    print(json.dumps({"out": str(path)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
