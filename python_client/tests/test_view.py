"""`python -m ciflow.view` and the shaded `rgb_array` frames, without a display: every
recording is saved to an `.rrd` file and read back with Rerun's own chunk reader."""

import json
import sys
import threading
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ciflow
from ciflow import _native, view

rerun = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, ciflow_cli  # noqa: E402

ASSETS = Path(__file__).parent / "assets"
POURING = "ciflow/Pouring-v0"


def rows_by_entity(path) -> dict[str, int]:
    """Rows on the `time` timeline per entity path of the recording at `path`."""
    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        if "time" in chunk.timeline_names:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    return rows


def text_logs(path, entity: str) -> list[str]:
    texts = []
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        if chunk.entity_path == entity:
            batch = chunk.to_record_batch()
            column = next(c for c in batch.schema.names if c.endswith("TextLog:text"))
            texts += [t[0] for t in batch.column(column).to_pylist() if t]
    return texts


@pytest.fixture(autouse=True)
def rerun_warnings_are_errors():
    # Rerun reports malformed components (a bad colour, a wrong length) as warnings and
    # drops them: here they fail the test.
    with warnings.catch_warnings():
        warnings.simplefilter("error", rerun.error_utils.RerunWarning)
        yield


def test_a_watched_session_is_recorded_with_its_bodies_and_one_row_per_sample(engine, tmp_path):
    endpoint, name = engine
    env = gym.make(POURING, engine=endpoint)
    env.reset(seed=1)
    client = _native.ClientHandle.open(connect=[endpoint])
    described = client.describe(name, "anonymous", env.unwrapped.session_id)
    assert described["task"] == POURING and described["num_envs"] == 1
    with pytest.raises(ciflow.CiflowError, match="unknown_session"):
        client.describe(name, "anonymous", "0123456789abcdef")

    recording = view.open_recording("test", save=str(tmp_path / "live.rrd"))
    watched = {}
    watcher = threading.Thread(target=lambda: watched.update(
        view.watch(recording, client, name, env.unwrapped.session_id, timeout=3.0)))
    watcher.start()
    threading.Event().wait(0.5)  # the subscription reaches the engine
    context = env.unwrapped.context_space.low
    for step in range(60):
        env.step(np.zeros(7))
        if step == 10:
            env.unwrapped.perturb_link_wrench(6, [0.0, 0.0, 5.0], duration=0.1)
        if step == 30:
            env.unwrapped.set_context(np.asarray(context) + 0.01)
        threading.Event().wait(0.02)  # under the engine's 60 Hz telemetry rate
    watcher.join()
    env.close()
    view.finish(recording)

    (track,) = watched.values()
    assert track.samples >= 40, track.samples
    rows = rows_by_entity(tmp_path / "live.rrd")
    root = f"/sessions/{env.unwrapped.session_id}"
    for entity in ("state", "command", "context", "reward", "world/cup", "world/pot",
                   "world/table", "world/robot/link1", "world/robot/fingers"):
        assert rows.get(f"{root}/{entity}") == track.samples, (entity, rows)
    events = text_logs(tmp_path / "live.rrd", f"{root}/events")
    assert any("context →" in t for t in events) and "push" in events, events


def test_a_dataset_is_recorded_episode_after_episode_with_its_pushes(tmp_path):
    _native.record_expert("pouring", str(tmp_path / "ds"), 2, seed=4,
                          kwargs={}, options={"push_force": 40.0})
    path = tmp_path / "ds.rrd"
    recording = view.open_recording("test", save=str(path))
    tracks = view.record_dataset(recording, str(tmp_path / "ds"))
    view.finish(recording)
    _, episodes = _native.read_dataset(str(tmp_path / "ds"))
    rows = rows_by_entity(path)
    for k, (track, episode) in enumerate(zip(tracks, episodes)):
        steps = len(np.frombuffer(episode["rewards"], dtype="<f8"))
        assert track.samples == steps + 1
        assert rows[f"/episodes/{k}/world/cup"] == steps + 1
        assert rows[f"/episodes/{k}/command"] == steps
        logs = text_logs(path, f"/episodes/{k}/events")
        assert "push" in logs, logs
        assert logs[-1].startswith(f"episode {k}")


def test_the_command_line_shows_the_episodes_asked_for_or_says_why_not(tmp_path, capsys):
    """``--episodes K`` is episode K (it used to mean K to the end), and a selection of no
    episode, or a file that cannot be read, is an error (exit 2) instead of an empty
    recording or a traceback."""
    _native.record_expert("limit-cycle", str(tmp_path / "ds"), 3, seed=0, kwargs={},
                          options={})
    save = ["--save", str(tmp_path / "ds.rrd")]
    for episodes, shown in (("1", [1]), ("1:", [1, 2]), (":2", [0, 1])):
        assert view.main(["--dataset", str(tmp_path / "ds"), "--episodes", episodes]
                         + save) == 0
        entities = rows_by_entity(tmp_path / "ds.rrd")
        assert sorted({int(e.split("/")[2]) for e in entities if e.startswith("/episodes/")}) \
            == shown, episodes
    for argv, message in (
        (["--dataset", str(tmp_path / "ds"), "--episodes", "3"], "select none of the 3"),
        (["--dataset", str(tmp_path / "nowhere")], "No such file"),
        (["--record", str(tmp_path / "ds" / "data" / "metadata.json")], "not a run recorded"),
    ):
        assert view.main(argv + save) == 2
        assert message in capsys.readouterr().err, argv
    for argv in (["--dataset", str(tmp_path / "ds"), "--episodes", "-1"],
                 ["--watch", "*", "--timeout", "0"]):
        with pytest.raises(SystemExit):
            view.main(argv + save)


def obstacle_run(obstacles: int) -> list[dict]:
    """20 expert steps of the obstacle task, its target moved 5 cm after the 11th."""
    env = gym.make("ciflow/Obstacle-v0", obstacles=obstacles)
    observation, _ = env.reset(seed=0)
    context = observation[4:]
    samples = []
    for step in range(20):
        action = env.unwrapped.expert_action()
        observation, reward, *_ = env.step(action)
        if step == 10:
            moved = context.copy()
            moved[-2:] += 0.05
            env.unwrapped.set_context(moved)
        samples.append({"time": 0.01 * (step + 1), "state": observation[:4],
                        "context": observation[4:], "command": action, "reward": reward})
    env.close()
    return samples


def test_a_perturbation_run_logs_its_pushes_and_context_changes(tmp_path):
    samples = obstacle_run(2)
    events = [{"kind": "push", "start": 0.05, "duration": 0.02}]
    path = tmp_path / "run.rrd"
    recording = view.open_recording("test", save=str(path))
    view.record_run(recording, "obstacle-avoidance", {"obstacles": 2}, samples, events)
    view.finish(recording)
    rows = rows_by_entity(path)
    assert rows["/run/world/point"] == 20
    assert rows["/run/world/obstacles/1"] == 20 and "/run/world/obstacles/2" not in rows
    logs = text_logs(path, "/run/events")
    assert logs[0].startswith("push") and any("context →" in t for t in logs)


def test_the_command_line_shows_a_recorded_run_and_refuses_a_record_without_its_task(tmp_path):
    samples = obstacle_run(1)
    record = {"task": "ciflow/Obstacle-v0", "kwargs": {"obstacles": 1}, "events": [],
              "samples": [{k: v.tolist() if isinstance(v, np.ndarray) else v
                           for k, v in s.items()} for s in samples]}
    (tmp_path / "run.json").write_text(json.dumps(record))
    assert view.main(["--record", str(tmp_path / "run.json"),
                      "--save", str(tmp_path / "run.rrd")]) == 0
    assert rows_by_entity(tmp_path / "run.rrd")["/run/world/point"] == len(samples)
    del record["task"]
    (tmp_path / "old.json").write_text(json.dumps(record))
    with pytest.raises(SystemExit):
        view.main(["--record", str(tmp_path / "old.json"), "--save", str(tmp_path / "x.rrd")])


def test_a_2d_policy_is_drawn_as_its_field_and_latent_grid_for_each_context(tmp_path):
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    ciflow_cli("demos", "--task", "obstacle-avoidance", "--episodes", "4",
               "--kwarg", "obstacles=1", "--out", tmp_path / "demos")
    ciflow_cli("train", "--task", "obstacle-avoidance", "--demos", tmp_path / "demos",
               "--out", tmp_path / "avoid", "--epochs", "2", "--layers", "2", "--hidden", "16,16")
    flow_field = _native.FlowField(str(tmp_path / "avoid"))
    path = tmp_path / "field.rrd"
    recording = view.open_recording("test", save=str(path))
    view.record_run(recording, "obstacle-avoidance", {"obstacles": 1}, obstacle_run(1), [],
                    flow_field=flow_field)
    # A policy of another task draws nothing on this one.
    view.record_run(recording, "ciflow/LimitCycle-v0", {}, [
        {"time": 0.0, "state": np.zeros(4), "context": np.zeros(1), "command": np.zeros(2),
         "reward": 0.0}], [], root="other", flow_field=flow_field)
    view.finish(recording)

    arrows = []
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        if chunk.entity_path == "/run/world/policy/field":
            batch = chunk.to_record_batch()
            column = next(c for c in batch.schema.names if c.endswith("Arrows3D:vectors"))
            arrows += [np.asarray(v) for v in batch.column(column).to_pylist()]
    rows = rows_by_entity(path)
    # Drawn for the first context and again after the target moved.
    assert rows["/run/world/policy/field"] == 2 == rows["/run/world/policy/latent_grid"]
    assert len(arrows) == 2 and arrows[0].shape == (20 * 20, 3)
    assert np.abs(arrows[0] - arrows[1]).max() > 1e-6, "the field follows the context"
    assert not any(entity.startswith("/other/world/policy") for entity in rows)


def test_a_body_is_drawn_as_its_own_solid():
    scenery = _native.Scenery("pouring")
    env = gym.make(POURING)
    observation, _ = env.reset(seed=0)
    env.close()
    bodies = {b["name"]: b for b in scenery.scene(observation.tolist())}
    kinds = {name: type(view.body_archetype(b)).__name__ for name, b in bodies.items()}
    assert kinds["pot"] == "Cylinders3D" and kinds["table"] == "Boxes3D"
    assert kinds["robot/link1"] == "Capsules3D" and kinds["spout"] == "Ellipsoids3D"
    # A capsule's Rerun pose puts its far end where ciflow's body ends.
    link = bodies["robot/link3"]
    capsule = view.body_archetype(link)
    length = capsule.lengths.as_arrow_array().to_pylist()[0]
    quaternion = capsule.quaternions.as_arrow_array().to_pylist()[0]
    end = np.asarray(link["from"]) + length * view._rotate(quaternion, [0, 0, 1])
    np.testing.assert_allclose(end, link["to"], atol=1e-6)
    with pytest.raises(ValueError, match="observation"):
        scenery.scene(observation[:-1].tolist())


def test_a_reach_arm_is_drawn_from_its_own_urdf():
    urdf = (Path(__file__).resolve().parents[2] / "engine/tests/assets/ur5e.urdf").read_text()
    scenery = _native.Scenery("ciflow/Reach-v0", {"urdf": urdf, "tool": "tool0"})
    env = gym.make("ciflow/Reach-v0", urdf=urdf, tool="tool0")
    observation, _ = env.reset(seed=0)
    env.close()
    bodies = {b["name"]: b for b in scenery.scene(observation.tolist())}
    links = [name for name in bodies if name.startswith("robot/")]
    assert 4 <= len(links) <= 7, links  # the UR5e's six joints, coincident frames merged
    np.testing.assert_allclose(bodies["goal"]["centre"], observation[-3:])


def test_a_urdf_with_visuals_is_drawn_with_its_own_geometry_posed_as_rerun_poses_it(tmp_path):
    """The UR5e with a box as every link's visual: the links' geometry is Rerun's URDF
    loader's, and each joint's logged transform (from ciflow's forward kinematics) equals
    the one Rerun's own URDF joint computes from the joint's angle."""
    from rerun.urdf import UrdfTree

    plain = (Path(__file__).resolve().parents[2] / "engine/tests/assets/ur5e.urdf").read_text()
    urdf = plain.replace("<inertial>", '<visual><geometry><box size="0.05 0.05 0.05"/>'
                                       "</geometry></visual><inertial>")
    assert urdf.count("<visual>") >= 6
    kwargs = {"urdf": urdf, "tool": "tool0"}
    env = gym.make("ciflow/Reach-v0", **kwargs)
    observation, _ = env.reset(seed=2)
    env.close()
    path = tmp_path / "urdf.rrd"
    recording = view.open_recording("test", save=str(path))
    track = view.Track(recording, "run", "ciflow/Reach-v0", kwargs)
    track.log(0.0, observation, 3)
    view.finish(recording)

    rows, transforms = {}, {}
    for chunk in RrdReader(str(path)).store().stream().to_chunks():
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
        if chunk.entity_path.startswith("/run/world/urdf_joints/"):
            batch = chunk.to_record_batch()
            # Row 0's first (only) instance of each component.
            value = {name.split(":")[-1]: batch.column(name).to_pylist()[0][0]
                     for name in batch.schema.names if "Transform3D" in name}
            transforms[chunk.entity_path.rsplit("/", 1)[1]] = value
    assert any("visual_geometries" in entity for entity in rows), sorted(rows)
    assert "/run/world/urdf_base" in rows, "the URDF's frames hang on the track's world"
    assert not any(entity.startswith("/run/world/robot/") for entity in rows)

    with open(tmp_path / "ur5e.urdf", "w") as file:
        file.write(urdf)
    tree = UrdfTree.from_file_path(str(tmp_path / "ur5e.urdf"))
    movable = [j for j in tree.joints() if j.joint_type in ("revolute", "continuous")]
    assert len(movable) == 6 and set(j.name for j in movable) <= set(transforms)
    for joint, q in zip(movable, observation[:6]):
        expected = {c.component_descriptor().component.split(":")[-1]:
                    c.as_arrow_array().to_pylist()[0]
                    for c in joint.compute_transform(float(q)).as_component_batches()}
        logged = transforms[joint.name]
        np.testing.assert_allclose(logged["translation"], expected["translation"], atol=1e-6)
        # q and −q are one rotation.
        sign = np.sign(np.dot(logged["quaternion"], expected["quaternion"]))
        np.testing.assert_allclose(sign * np.asarray(logged["quaternion"]),
                                   expected["quaternion"], atol=1e-6)


def test_the_pouring_frame_of_a_known_state_matches_its_reference():
    """The reference is `assets/pouring_frame.png`, written by this test's own code from
    seed 0 (`python tests/test_view.py` rewrites it after a deliberate change)."""
    import matplotlib.image

    frame = pouring_frame()
    reference = (matplotlib.image.imread(ASSETS / "pouring_frame.png")[..., :3] * 255).round()
    difference = np.abs(frame.astype(float) - reference)
    assert frame.shape == reference.shape
    assert difference.mean() < 1.0, difference.mean()
    assert (difference.max(axis=-1) > 16).mean() < 0.005
    # Shaded solids: many more distinct colours than a line drawing's handful.
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 200


def pouring_frame() -> np.ndarray:
    env = gym.make(POURING, render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(100):
        env.step(env.unwrapped.expert_action())
    frame = env.render()
    env.close()
    return frame


if __name__ == "__main__":
    import matplotlib.pyplot

    ASSETS.mkdir(exist_ok=True)
    matplotlib.pyplot.imsave(ASSETS / "pouring_frame.png", pouring_frame())
    ciflow  # the package registers the environments on import
