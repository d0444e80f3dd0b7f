"""Demonstrations from elsewhere: a Minari dataset written by Minari itself (HDF5, its
default storage; ``Dict`` observations as Gymnasium-Robotics lays them out) and a LeRobot
v3.0 dataset written by ``lerobot`` itself (the committed fixture, see
``lerobot/write_fixture.py``) are converted by ``python -m ciflow.convert`` and trained on
by ``ciflow train --state ... --context``; bad fields, lengths, values and time steps are
refused with messages that say where."""

import json
import re
import subprocess
import sys
from pathlib import Path

import minari
import numpy as np
import pytest
from gymnasium import spaces
from minari.data_collector.episode_buffer import EpisodeBuffer

import ciflow
from ciflow import _native
from ciflow.convert import ConversionError, Field, convert, to_lerobot

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, free_port, start_process  # noqa: E402

DT = 0.05
STEPS = 60
LEROBOT_FIXTURE = Path(__file__).resolve().parent / "lerobot" / "fixture"
# Minari asks datasets it writes for an evaluation environment and spec; these have none.
pytestmark = pytest.mark.filterwarnings("ignore:.*(eval_env|env_spec is None).*:UserWarning")


def vector(n: int) -> spaces.Box:
    return spaces.Box(-np.inf, np.inf, (n,), np.float64)


OBSERVATION_SPACE = spaces.Dict(
    {"observation": vector(4), "achieved_goal": vector(2), "desired_goal": vector(2)}
)
ACTION_SPACE = spaces.Box(-10.0, 10.0, (2,), np.float64)


def reach(seed: int, corrupt: bool = False) -> EpisodeBuffer:
    """A point mass under a PD law from a random start to a random goal."""
    rng = np.random.default_rng(seed)
    x, v, goal = rng.uniform(-1, 1, 2), np.zeros(2), rng.uniform(-0.3, 0.3, 2)
    observations = {"observation": [], "achieved_goal": [], "desired_goal": []}
    actions, rewards, distance, task = [], [], [], []

    def observe():
        observations["observation"].append(np.concatenate([x, v]))
        observations["achieved_goal"].append(x.copy())
        observations["desired_goal"].append(goal.copy())
        distance.append(float(np.linalg.norm(x - goal)))
        task.append(np.concatenate([[STEPS * DT], goal]))  # the time limit, then the goal

    observe()
    for _ in range(STEPS):
        action = np.clip(16 * (goal - x) - 8 * v, -10, 10)
        v = v + DT * action
        x = x + DT * v
        actions.append(action)
        rewards.append(-float(np.linalg.norm(x - goal)))
        observe()
    if corrupt:
        observations["achieved_goal"][STEPS // 2] = np.array([np.nan, 0.0])
    return EpisodeBuffer(
        id=seed, seed=seed,
        observations={k: np.array(rows) for k, rows in observations.items()},
        actions=np.array(actions), rewards=rewards,
        terminations=[False] * STEPS, truncations=[False] * (STEPS - 1) + [True],
        infos={"distance": np.array(distance), "task": np.array(task)},
    )


def foreign_dataset(root, name: str, episodes: int, corrupt: bool = False):
    """A dataset Minari writes itself, in its default storage; returns its directory."""
    minari.create_dataset_from_buffers(
        f"test/{name}-v0", [reach(i, corrupt and i == 1) for i in range(episodes)],
        observation_space=OBSERVATION_SPACE, action_space=ACTION_SPACE,
        algorithm_name="pd", author="someone", author_email="someone@example.org",
        code_permalink="https://example.org", description="point reaching",
    )
    return root / "test" / f"{name}-v0"


@pytest.fixture
def minari_root(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return tmp_path / "minari"


def test_fields_parse_paths_ranges_and_indices():
    assert Field.parse("observations[0:2]").columns == slice(0, 2)
    assert Field.parse("observations/desired_goal").path == ("observations", "desired_goal")
    assert Field.parse("infos/goal[3]").columns == slice(3, 4)
    assert Field.parse("observations[-1]").columns == slice(-1, None)
    for bad in ("observations[0:2", "observations//x", "observations[a]", "[0:2]"):
        with pytest.raises(ConversionError):
            Field.parse(bad)


def test_a_dataset_written_by_minari_converts_exactly(minari_root, tmp_path):
    source = foreign_dataset(minari_root, "reach", 3)
    out = convert(source, tmp_path / "out", "observations/achieved_goal",
                  "observations/desired_goal", dt=DT)
    spec, episodes = _native.read_dataset(str(out))
    assert spec["control_dt"] == DT
    assert len(spec["observation_space"]["low"]) == 6  # [y, ẏ, c]
    assert len(spec["context_space"]["low"]) == 2
    for episode, want in zip(episodes, minari.MinariDataset(str(source / "data")).iterate_episodes()):
        observations = np.frombuffer(episode["observations"], "<f8").reshape(-1, 6)
        np.testing.assert_array_equal(observations[:, :2], want.observations["achieved_goal"])
        np.testing.assert_array_equal(observations[:, 4:], want.observations["desired_goal"])
        np.testing.assert_allclose(
            observations[:-1, 2:4], np.diff(want.observations["achieved_goal"], axis=0) / DT
        )
        contexts = np.frombuffer(episode["contexts"], "<f8").reshape(-1, 2)
        np.testing.assert_array_equal(contexts, want.observations["desired_goal"])
        np.testing.assert_array_equal(
            np.frombuffer(episode["actions"], "<f8").reshape(-1, 2), want.actions
        )


def test_a_dataset_written_by_lerobot_converts_exactly(tmp_path):
    """Frames are observations in frame order, the time step is 1 / fps, the last frame's
    action is left out (no step follows it), and float32 values convert exactly."""
    import pyarrow.parquet as pq

    out = convert(LEROBOT_FIXTURE, tmp_path / "out", "observation.state[0:2]", "observation.goal")
    spec, episodes = _native.read_dataset(str(out))
    assert spec["control_dt"] == 1 / 20
    # The directory's name becomes an id Minari opens (the bare name is not one).
    assert spec["dataset_id"] == f"lerobot/{LEROBOT_FIXTURE.name}-v0"
    assert minari.MinariDataset(str(out / "data")).total_episodes == 3
    table = pq.read_table(LEROBOT_FIXTURE / "data" / "chunk-000" / "file-000.parquet")
    frames = table.to_pydict()
    assert len(episodes) == len(set(frames["episode_index"])) == 3
    for number, episode in enumerate(episodes):
        rows = [i for i, e in enumerate(frames["episode_index"]) if e == number]
        rows.sort(key=lambda i: frames["frame_index"][i])
        state = np.array([frames["observation.state"][i] for i in rows], dtype=np.float32)
        goal = np.array([frames["observation.goal"][i] for i in rows], dtype=np.float32)
        action = np.array([frames["action"][i] for i in rows], dtype=np.float32)
        observations = np.frombuffer(episode["observations"], "<f8").reshape(-1, 6)
        np.testing.assert_array_equal(observations[:, :2], state[:, :2].astype(np.float64))
        np.testing.assert_array_equal(observations[:, 4:], goal.astype(np.float64))
        np.testing.assert_array_equal(
            np.frombuffer(episode["actions"], "<f8").reshape(-1, 2), action[:-1].astype(np.float64)
        )
    with pytest.raises(ConversionError, match="unit mismatch"):
        convert(LEROBOT_FIXTURE, tmp_path / "ms", "observation.state[0:2]", dt=0.01)
    with pytest.raises(ConversionError, match="no 'observation.images'"):
        convert(LEROBOT_FIXTURE, tmp_path / "img", "observation.images")


def test_bad_requests_are_refused_with_where_and_why(minari_root, tmp_path):
    source = foreign_dataset(minari_root, "reach", 2)
    cases = {
        "states[0:2]": "no 'states' .there: actions, infos, observations, rewards",
        "observations/goal": "no 'observations/goal'",
        "observations": "is a Dict",
        "observations/achieved_goal[1:1]": "selects no column",
        # numpy would quietly take the columns there are.
        "observations/achieved_goal[0:9]": "reaches past the 2 columns",
        "observations/achieved_goal[5]": "reaches past the 2 columns",
    }
    for state, message in cases.items():
        with pytest.raises(ConversionError, match=message):
            convert(source, tmp_path / "x", state, None, dt=DT)
    with pytest.raises(ConversionError, match="context 'actions' has 60 rows, the state"):
        convert(source, tmp_path / "x", "observations/achieved_goal", "actions", dt=DT)
    with pytest.raises(ConversionError, match="give it with --dt"):
        convert(source, tmp_path / "x", "observations/achieved_goal")
    with pytest.raises(ConversionError, match="not a positive number"):
        convert(source, tmp_path / "x", "observations/achieved_goal", dt=float("nan"))
    # Replacing the source, or a directory holding it, would delete it.
    before = sorted(str(p) for p in source.rglob("*"))
    for out in (source, source.parent):
        with pytest.raises(ConversionError, match="is or holds the source"):
            convert(source, out, "observations/achieved_goal", dt=DT, overwrite=True)
        with pytest.raises(ConversionError, match="is or holds the source"):
            to_lerobot(source, out, overwrite=True)
    assert sorted(str(p) for p in source.rglob("*")) == before, "the source is untouched"
    corrupt = foreign_dataset(minari_root, "corrupt", 2, corrupt=True)
    with pytest.raises(ConversionError, match="episode 1: state is NaN or infinite at step 30"):
        convert(corrupt, tmp_path / "x", "observations/achieved_goal", dt=DT)
    assert not (tmp_path / "x").exists()


def test_a_ciflow_dataset_s_own_time_step_must_agree_with_dt(tmp_path):
    _native.record_expert("obstacle-avoidance", str(tmp_path / "ds"), 1, kwargs={"obstacles": 1})
    convert(tmp_path / "ds", tmp_path / "same", "observations[0:2]", "observations[4:]")
    with pytest.raises(ConversionError, match="unit mismatch"):
        convert(tmp_path / "ds", tmp_path / "ms", "observations[0:2]", dt=10.0)


def test_ciflow_train_fits_a_dataset_from_elsewhere(minari_root, tmp_path):
    """End to end: `ciflow train` converts (beside the checkpoint) and fits; the
    checkpoint's model has the named fields' dimensions and acts."""
    source = foreign_dataset(minari_root, "reach", 12)
    out = tmp_path / "policy"
    result = subprocess.run(
        [str(BINARY), "train", "--task", "lasa", "--demos", str(source), "--state",
         "observations/achieved_goal", "--context", "observations/desired_goal", "--dt",
         str(DT), "--epochs", "2", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stderr
    config = json.loads((out / "config.json").read_text())
    assert (config["state_dim"], config["context_dim"], config["dt"]) == (2, 2, DT)
    spec, episodes = _native.read_dataset(str(out / "demonstrations"))
    assert len(episodes) == 12 and spec["control_dt"] == DT

    lerobot = subprocess.run(
        [str(BINARY), "train", "--task", "lasa", "--demos", str(LEROBOT_FIXTURE), "--state",
         "observation.state[0:2]", "--context", "observation.goal", "--epochs", "1", "--out",
         str(tmp_path / "from-lerobot")],
        capture_output=True, text=True, timeout=600,
    )
    assert lerobot.returncode == 0, lerobot.stderr
    config = json.loads((tmp_path / "from-lerobot" / "config.json").read_text())
    assert (config["state_dim"], config["context_dim"], config["dt"]) == (2, 2, 1 / 20)

    # A context that is more than the state's target: which entries are the target is
    # named, not guessed.
    def train_with_wider_context(*extra):
        return subprocess.run(
            [str(BINARY), "train", "--task", "lasa", "--demos", str(source), "--state",
             "observations/achieved_goal", "--context", "infos/task", "--dt", str(DT),
             "--epochs", "1", *extra, "--out", str(tmp_path / "wider")],
            capture_output=True, text=True, timeout=600,
        )
    guessed = train_with_wider_context()
    assert guessed.returncode != 0
    assert "3-D context is not the 2-D state's target" in guessed.stderr, guessed.stderr
    assert "--goal-context-indices 0,1" in guessed.stderr
    assert not (tmp_path / "wider" / "config.json").exists()
    named = train_with_wider_context("--goal-context-indices", "1,2")
    assert named.returncode == 0, named.stderr
    config = json.loads((tmp_path / "wider" / "config.json").read_text())
    assert (config["context_dim"], config["goal_context_indices"]) == (3, [1, 2])

    # Served on its own observations [q, q̇, c] (its shapes fit no task), it acts from
    # Python; a batch answers row by row.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    engine = start_process([str(BINARY), "serve", "--listen", endpoint, "--name", "own-data",
                            "--own-data-policy", f"mine={tmp_path / 'wider'}"])
    try:
        policy = ciflow.Policy("mine", engine=endpoint)
        assert (policy.task, policy.observation_dim, policy.action_dim) == ("own-data", 7, 2)
        rows = np.array([[0.5, -0.5, 0.0, 0.0, 3.0, 0.1, -0.2],
                         [-0.2, 0.4, 0.1, 0.0, 3.0, 0.2, 0.2]])
        batch = policy.act(rows)
        assert batch.shape == (2, 2) and np.isfinite(batch).all()
        np.testing.assert_array_equal(batch[1], policy.act(rows[1]))
    finally:
        engine.terminate()
        engine.wait(timeout=10)

    # Without --state, the dataset's Dict spaces are not ciflow's layout: the fix is named.
    unnamed = subprocess.run(
        [str(BINARY), "train", "--task", "lasa", "--demos", str(source), "--out",
         str(tmp_path / "unnamed")],
        capture_output=True, text=True, timeout=600,
    )
    assert unnamed.returncode != 0
    assert "is a Dict space" in unnamed.stderr and "--state FIELD" in unnamed.stderr, \
        unnamed.stderr

    refused = subprocess.run(
        [str(BINARY), "train", "--task", "lasa", "--demos", str(source), "--state",
         "observations/nothing", "--dt", str(DT), "--out", str(tmp_path / "refused")],
        capture_output=True, text=True, timeout=600,
    )
    assert refused.returncode != 0
    assert "no 'observations/nothing'" in refused.stderr
    assert "Traceback" not in refused.stderr
    assert not (tmp_path / "refused" / "config.json").exists()



def test_a_damaged_lerobot_dataset_is_refused_naming_the_episode_and_frame(tmp_path):
    """A frame without its state, a state row of another length, and an episode of one
    frame (no step) are each refused with the field, episode and frame named."""
    import shutil

    import pyarrow as pa
    import pyarrow.parquet as pq

    def damaged(name, change):
        root = tmp_path / name
        shutil.copytree(LEROBOT_FIXTURE, root)
        data = next((root / "data").glob("**/*.parquet"))
        pq.write_table(change(pq.read_table(data)), data)
        return root

    def with_states(table, rows):
        state = pa.array(rows, pa.list_(pa.float32()))
        return table.set_column(table.schema.get_field_index("observation.state"),
                                "observation.state", state)

    def states(table):
        return table.column("observation.state").to_pylist()

    def without(table):
        rows = states(table)
        rows[30] = None  # episode 1, frame 5
        return with_states(table, rows)

    def ragged(table):
        rows = states(table)
        rows[60] = rows[60][:3]  # episode 2, frame 10
        return with_states(table, rows)

    def one_frame(table):
        keep = [i for i, e in enumerate(table.column("episode_index").to_pylist())
                if e != 1 or i == 25]
        return table.take(keep)

    for name, change, message in (
        ("null", without, "'observation.state' has no value at episode 1, frame 5"),
        ("ragged", ragged, "'observation.state' holds 3 value(s) at episode 2, frame 10 but 4"),
        ("short", one_frame, "episode 1: 1 frame(s), no step"),
    ):
        with pytest.raises(ConversionError, match=re.escape(message)):
            convert(damaged(name, change), tmp_path / f"{name}-out", "observation.state[0:2]",
                    "observation.goal")
        assert not (tmp_path / f"{name}-out").exists()


def test_a_dataset_without_context_goes_to_lerobot_and_back(tmp_path):
    """LeRobot has no zero-width feature: a context-free dataset (here one converted
    without --context) is written without an environment state (it used to fail in
    pyarrow) and reads back the same, up to float32."""
    _native.record_expert("limit-cycle", str(tmp_path / "cycle"), 2, seed=1)
    free = convert(tmp_path / "cycle", tmp_path / "free", "observations[0:2]")
    lerobot = to_lerobot(free, tmp_path / "lerobot")
    info = json.loads((lerobot / "meta" / "info.json").read_text())
    assert "observation.environment_state" not in info["features"]
    back = convert(lerobot, tmp_path / "back", "observation.state",
                   velocity="observation.velocity")
    (_, original), (spec, returned) = (_native.read_dataset(str(p)) for p in (free, back))
    assert spec["context_space"]["low"] == []
    for a, b in zip(original, returned, strict=True):
        np.testing.assert_array_equal(
            np.frombuffer(b["observations"], "<f8"),
            np.frombuffer(a["observations"], "<f8").astype(np.float32).astype(np.float64))


def test_minari_to_lerobot_to_minari_is_exact_up_to_float32(tmp_path):
    """A ciflow dataset written as LeRobot v3.0 (float32, as LeRobot stores numbers) and
    read back holds the same episodes rounded to float32, nothing else changed; the
    layout is the one `lerobot` writes (the fixture's files and columns)."""
    import pyarrow.parquet as pq

    _native.record_expert("pouring", str(tmp_path / "ciflow"), 2, seed=4)
    lerobot = to_lerobot(tmp_path / "ciflow", tmp_path / "lerobot")
    back = convert(lerobot, tmp_path / "back", "observation.state",
                   "observation.environment_state", velocity="observation.velocity")
    spec, episodes = _native.read_dataset(str(tmp_path / "ciflow"))
    back_spec, back_episodes = _native.read_dataset(str(back))
    assert back_spec["control_dt"] == spec["control_dt"]
    assert len(back_episodes) == len(episodes) == 2

    def float32(data: bytes) -> np.ndarray:
        return np.frombuffer(data, "<f8").astype(np.float32).astype(np.float64)

    for original, returned in zip(episodes, back_episodes):
        for key in ("observations", "actions", "rewards", "contexts"):
            np.testing.assert_array_equal(np.frombuffer(returned[key], "<f8"),
                                          float32(original[key]), err_msg=key)
        assert returned["terminations"] == original["terminations"]

    index_columns = ("timestamp", "frame_index", "episode_index", "index", "task_index")

    def layout(root):
        files = sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())
        info = json.loads((root / "meta" / "info.json").read_text())
        data = pq.read_schema(root / "data" / "chunk-000" / "file-000.parquet")
        episodes = pq.read_schema(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
        return (files, sorted(k for k in info if k != "features"),
                {f.name: f.type for f in data if f.name in index_columns},
                sorted(n for n in episodes.names if not n.startswith("stats/")))

    assert layout(lerobot) == layout(LEROBOT_FIXTURE)
    with pytest.raises(FileExistsError):
        to_lerobot(tmp_path / "ciflow", tmp_path / "lerobot")


def test_both_recorders_write_lerobot(engine, tmp_path):
    """`ciflow demos --format lerobot` and `python -m ciflow.record --format lerobot` write
    the same LeRobot dataset, and leave no Minari staging directory behind."""
    import pyarrow.parquet as pq

    endpoint, _name = engine
    args = ["--task", "obstacle-avoidance", "--episodes", "2", "--seed", "7", "--kwarg",
            "obstacles=1", "--format", "lerobot"]
    subprocess.run([str(BINARY), "demos", *args, "--out", str(tmp_path / "rust")],
                   check=True, capture_output=True, timeout=300)
    subprocess.run([sys.executable, "-m", "ciflow.record", *args, "--out", str(tmp_path / "py"),
                    "--engine", endpoint, "--no-publish", "--quiet"],
                   check=True, capture_output=True, timeout=300)
    for name in ("data/chunk-000/file-000.parquet", "meta/episodes/chunk-000/file-000.parquet",
                 "meta/tasks.parquet"):
        assert pq.read_table(tmp_path / "py" / name).equals(pq.read_table(tmp_path / "rust" / name))
    for name in ("meta/info.json", "meta/stats.json"):
        assert (tmp_path / "py" / name).read_text() == (tmp_path / "rust" / name).read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["py", "rust"]
