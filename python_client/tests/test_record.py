"""``ciflow.record``: expert episodes through ``gymnasium.make`` and an engine in another
process give the same dataset as ``ciflow demos`` (the in-process Rust recorder), which
Minari opens; each episode is published on the episode channel as it finishes."""

import importlib.metadata
import json
import subprocess
import sys
import threading
import warnings

import gymnasium as gym
import minari
import msgpack
import numpy as np
import pytest
import zenoh
from minari.utils import get_dataset_spec_dict

from ciflow import _native
from ciflow.record import record

TASK = "obstacle-avoidance"
KWARGS = {"obstacles": 1}


class EpisodeListener:
    """A plain Zenoh client subscribed to ``ciflow/v2/episodes/<task>/*``."""

    def __init__(self, endpoint: str, task: str):
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(config)
        self.messages = []
        self.arrived = threading.Condition()
        self.subscriber = self.session.declare_subscriber(
            f"ciflow/v2/episodes/{task}/*", self._on_sample
        )

    def _on_sample(self, sample):
        message = msgpack.unpackb(sample.payload.to_bytes())
        with self.arrived:
            self.messages.append((str(sample.key_expr), message))
            self.arrived.notify_all()

    def wait_for(self, count: int, timeout: float = 30.0):
        with self.arrived:
            self.arrived.wait_for(lambda: len(self.messages) >= count, timeout)
            return list(self.messages)

    def close(self):
        self.session.close()


def rows(data: bytes, width: int) -> np.ndarray:
    return np.frombuffer(data, "<f8").reshape(-1, width)


def test_recorder_matches_ciflow_demos_publishes_episodes_and_opens_in_minari(engine, tmp_path):
    endpoint, _name = engine
    listener = EpisodeListener(endpoint, TASK)
    try:
        result = record(
            "ciflow/Obstacle-v0", 3, tmp_path / "py", seed=5, kwargs=KWARGS,
            engine=endpoint, recorder="test-rec", progress=False,
        )
        messages = listener.wait_for(3)
    finally:
        listener.close()
    assert result.path == tmp_path / "py"
    assert result.key == f"ciflow/v2/episodes/{TASK}/test-rec"
    _native.record_expert(TASK, str(tmp_path / "rust"), 3, seed=5, kwargs=KWARGS)

    for name in ("data/metadata.json", *(f"data/{i}/metadata.json" for i in range(3))):
        assert (tmp_path / "py" / name).read_text() == (tmp_path / "rust" / name).read_text(), name
    spec, recorded = _native.read_dataset(str(tmp_path / "py"))
    rust_spec, expected = _native.read_dataset(str(tmp_path / "rust"))
    assert spec == rust_spec
    assert spec["dataset_id"] == result.dataset_id == "ciflow/obstacle-avoidance-expert-v0"
    assert len(recorded) == 3
    for got, want in zip(recorded, expected):
        assert got.keys() == want.keys()
        for key in want:
            assert got[key] == want[key], key
    assert [e["seed"] for e in recorded] == [5, 6, 7]
    assert result.steps == sum(len(e["rewards"]) // 8 for e in recorded) > 3

    obs_dim = len(spec["observation_space"]["low"])
    act_dim = len(spec["action_space"]["low"])
    dataset = minari.MinariDataset(str(tmp_path / "py" / "data"))
    assert dataset.total_episodes == 3
    for episode, want in zip(dataset.iterate_episodes(), expected):
        np.testing.assert_array_equal(episode.observations, rows(want["observations"], obs_dim))
        np.testing.assert_array_equal(episode.actions, rows(want["actions"], act_dim))

    assert [key for key, _ in messages] == [result.key] * 3
    for index, ((_, message), want) in enumerate(zip(messages, expected)):
        assert message["v"] == 2
        assert message["task"] == "ciflow/Obstacle-v0"
        assert (message["recorder"], message["index"], message["seed"]) == ("test-rec", index, 5 + index)
        assert message["dataset_id"] == result.dataset_id
        assert (message["observation_dim"], message["action_dim"]) == (obs_dim, act_dim)
        for key in ("observations", "actions", "contexts", "rewards"):
            assert message[key] == want[key], key
        assert message["terminated"] == bool(want["terminations"][-1])
        assert message["truncated"] == bool(want["truncations"][-1])


def test_bad_input_is_rejected_before_anything_is_written(engine, tmp_path):
    endpoint, _name = engine
    common = dict(engine=endpoint, progress=False, publish=False)
    with pytest.raises(ValueError, match="unknown task"):
        record("juggling", 1, tmp_path / "a", **common)
    for episodes in (0, -2, 1.5, True):
        with pytest.raises(ValueError, match="episodes"):
            record(TASK, episodes, tmp_path / "a", **common)
    with pytest.raises(ValueError, match="seed"):
        record(TASK, 1, tmp_path / "a", seed=-1, **common)
    with pytest.raises(ValueError, match="obstacles"):
        record(TASK, 1, tmp_path / "a", kwargs={"obstacles": "many"}, **common)
    with pytest.raises(ValueError, match="nothing to do"):
        record(TASK, 1, None, **common)
    with pytest.raises(ValueError, match="given as a construction argument"):
        record(TASK, 1, tmp_path / "a", kwargs={"obstacles": 2}, options={"obstacles": 3},
               **common)
    with pytest.raises(ValueError, match="not one Minari opens"):
        record(TASK, 1, tmp_path / "a", dataset_id="", **common)
    (tmp_path / "taken").mkdir()
    with pytest.raises(FileExistsError):
        record(TASK, 1, tmp_path / "taken", **common)
    # Overwriting replaces a dataset, never a directory of other files.
    (tmp_path / "taken" / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="is not a dataset"):
        record(TASK, 1, tmp_path / "taken", overwrite=True, **common)
    assert (tmp_path / "taken" / "notes.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"]


def test_dataset_ids_are_refused_exactly_where_minari_refuses_them():
    """A dataset whose id Minari cannot parse would be written and then fail to open."""
    from minari.dataset.minari_dataset import parse_dataset_id

    space = {"low": [-1.0], "high": [1.0], "dtype": "float64"}
    env_spec = {"id": TASK, "control_dt": 0.01, "observation_space": space,
                "action_space": space, "context_space": space}
    ids = ["ciflow/limit-cycle-expert-v0", "x-v0", "a/b/c-v12", "ab/x--v1", "é_1-v3", "",
           "foo", "foo-v", "-v1", "a/x-v0", "/ab/x-v1", "ab/-v1", "ns/x y-v1", "x-v1.2",
           "ab//x-v2", "x-v0-v1"]
    for dataset_id in ids:
        try:
            parse_dataset_id(dataset_id)
            minari_opens = True
        except (ValueError, TypeError):  # TypeError: an id without a version
            minari_opens = False
        try:
            _native.DatasetSpec(env_spec, dataset_id)
            accepted = True
        except ValueError as error:
            assert "not one Minari opens" in str(error)
            accepted = False
        assert accepted == minari_opens, dataset_id


def test_command_line_records_a_dataset_and_reports_errors(engine, tmp_path):
    endpoint, _name = engine
    out = tmp_path / "cycle"
    command = [sys.executable, "-m", "ciflow.record", "--task", "limit-cycle", "--episodes",
               "2", "--seed", "3", "--out", str(out), "--engine", endpoint, "--no-publish",
               "--quiet"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "2 episodes" in done.stdout
    spec, episodes = _native.read_dataset(str(out))
    assert spec["env_id"] == "ciflow/LimitCycle-v0"
    assert [e["seed"] for e in episodes] == [3, 4]

    again = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert again.returncode == 2 and "already exists" in again.stderr
    bad = subprocess.run(command[:-6] + ["--kwarg", "speed"], capture_output=True, text=True)
    assert bad.returncode != 0 and "NAME=VALUE" in bad.stderr


def test_a_dataset_recovers_the_environment_that_recorded_it(engine, tmp_path):
    """Minari's ``recover_environment()`` rebuilds the task with its construction
    arguments (2 obstacles, not the default 3) from the dataset's ``env_spec``, and
    ``minari show``'s tables are complete."""
    endpoint, _name = engine
    _native.record_expert(TASK, str(tmp_path / "ds"), 2, seed=3, kwargs={"obstacles": 2})
    dataset = minari.MinariDataset(str(tmp_path / "ds" / "data"))
    assert dataset.env_spec.kwargs == {"task": "ciflow/Obstacle-v0", "obstacles": 2}
    assert dataset.env_spec.entry_point == gym.spec("ciflow/Obstacle-v0").entry_point

    with warnings.catch_warnings():
        # Minari warns when the dataset's `requirements` are not installed.
        warnings.filterwarnings("error", message=".*(not installed|does not meet).*")
        env = dataset.recover_environment(engine=endpoint)
    try:
        assert env.observation_space == dataset.observation_space
        assert env.action_space == dataset.action_space
        first = next(dataset.iterate_episodes())
        observation, _info = env.reset(seed=3)
        np.testing.assert_array_equal(observation, first.observations[0])
        wrong = gym.make("ciflow/Obstacle-v0", engine=endpoint)  # 3 obstacles
        try:
            assert wrong.observation_space != dataset.observation_space
        finally:
            wrong.close()
    finally:
        env.close()

    metadata = dataset.storage.metadata
    shown = get_dataset_spec_dict(metadata)
    assert shown["Total Steps"] == str(dataset.total_steps)
    assert shown["Author"] == "ciflow"
    assert "Dataset Observation Space" in shown and "Dataset Action Space" in shown
    assert "ciflow/Obstacle-v0 (obstacles=2)" in metadata["description"]
    assert metadata["requirements"] == [f"ciflow=={importlib.metadata.version('ciflow')}"]
