"""`ciflow demos` datasets open with plain Minari / pyarrow, without ciflow installed."""

import json
import os
import pathlib
import subprocess

import minari
import numpy as np
import pyarrow.ipc as ipc
import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]


def ciflow_binary() -> pathlib.Path:
    """The CLI built by `cargo build --release` (or CIFLOW_BIN)."""
    if "CIFLOW_BIN" in os.environ:
        return pathlib.Path(os.environ["CIFLOW_BIN"])
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    binary = target / "release" / "ciflow"
    if not binary.exists():
        subprocess.run(["cargo", "build", "--release", "--bin", "ciflow"], cwd=REPO, check=True)
    return binary


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("minari")
    made = {}
    for task, extra in [
        ("limit-cycle", []),
        ("obstacle-avoidance", ["--kwarg", "obstacles=2"]),
        ("lasa", ["--kwarg", "shape=Sshape", "--option", "start_noise=3"]),
    ]:
        out = root / "ciflow" / f"{task}-expert-v0"
        subprocess.run(
            [str(ciflow_binary()), "demos", "--task", task, "--episodes", "3", "--seed", "5",
             "--out", str(out), *extra],
            check=True,
        )
        made[task] = out
    return root, made


def test_minari_load_dataset_reads_the_episodes(datasets, monkeypatch):
    root, made = datasets
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    dataset = minari.load_dataset("ciflow/obstacle-avoidance-expert-v0")
    assert dataset.total_episodes == 3
    assert dataset.observation_space.shape == (4 + 6,)
    assert dataset.action_space.shape == (2,)
    total = 0
    for episode in dataset.iterate_episodes():
        steps = len(episode.actions)
        total += steps
        assert episode.observations.shape == (steps + 1, 10)
        assert episode.rewards.shape == episode.terminations.shape == (steps,)
        # The context is stored explicitly and is the observation's tail.
        np.testing.assert_array_equal(episode.infos["context"], episode.observations[:, 4:])
        # Actions are accelerations: v[t+1] = v[t] + a[t] dt.
        dt = dataset.storage.metadata["ciflow"]["control_dt"]
        np.testing.assert_allclose(
            episode.observations[1:, 2:4],
            episode.observations[:-1, 2:4] + dt * episode.actions,
            atol=1e-9,
        )
        assert episode.terminations[-1] and episode.infos["is_success"][-1] == 1.0
    assert total == dataset.total_steps


def test_episode_metadata_and_files_follow_minari_layout(datasets):
    _, made = datasets
    data = made["limit-cycle"] / "data"
    metadata = json.loads((data / "metadata.json").read_text())
    assert metadata["data_format"] == "arrow"
    assert metadata["dataset_id"] == "ciflow/limit-cycle-expert-v0"
    seeds = [json.loads((data / str(i) / "metadata.json").read_text())["seed"] for i in range(3)]
    assert seeds == [5, 6, 7]
    table = ipc.open_file(data / "0" / "part-0.arrow").read_all()
    assert table.column_names == [
        "observations", "actions", "rewards", "terminations", "truncations", "infos"]
    episode = next(iter(minari.MinariDataset(data).iterate_episodes()))
    assert episode.truncations[-1]


def test_lasa_dataset_is_in_millimetres_and_ends_at_the_goal(datasets):
    _, made = datasets
    dataset = minari.MinariDataset(made["lasa"] / "data")
    assert dataset.storage.metadata["ciflow"]["env_id"] == "ciflow/Lasa-v0"
    assert dataset.observation_space.shape == (6,)
    for episode in dataset.iterate_episodes():
        # The shape given by name is stored by index (Sshape is the 25th of 30).
        assert set(episode.infos["shape"]) == {24.0}
        # The goal context is the dataset's origin; the paths start tens of mm from it.
        np.testing.assert_array_equal(episode.infos["context"], 0.0)
        assert 30.0 < np.linalg.norm(episode.observations[0, :2]) < 70.0
        assert episode.terminations[-1] and episode.infos["is_success"][-1] == 1.0
        assert np.linalg.norm(episode.observations[-1, :2]) < 1.0
