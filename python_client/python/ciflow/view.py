"""``python -m ciflow.view``: watch ciflow sessions, datasets and perturbation runs in
Rerun (https://rerun.io), the 3-D viewer robotics people already use.

What to show (one of):

* ``--watch ENGINE`` — every session of the engine named ENGINE, live, as their telemetry
  arrives (``--watch '*'``: every engine); ``--session ID`` narrows it to one session;
  ``--engine``/``--zenoh-config`` say how to reach the engines, as for ``ciflow.perturb``;
* ``--dataset DIR`` — every episode of a ciflow (Minari) dataset, one after another on
  the ``time`` timeline (each episode under ``episodes/<k>``);
* ``--record traces.json`` — a run recorded by ``python -m ciflow.perturb --record``,
  with its pushes and context changes.

Where to show it: ``--spawn`` (default) starts a native viewer, ``--serve`` serves a
web viewer (open the printed URL), ``--save FILE.rrd`` writes a recording anyone can
open with ``rerun FILE.rrd``.

Each session or episode logs, under its own path: ``world/…`` the task's bodies (the
arm's links as capsules between its joint origins, cup, pot, table, obstacles, target,
outline — the same bodies ``render()`` shades), ``state``, ``command``, ``context`` and
``reward`` as time series (one line per coordinate), ``events`` (context changes, pushes,
episode ends) as a text log, and with ``--policy CHECKPOINT`` (a 2-D task's flow) the
policy's vector field, noise-free rollouts and latent-grid deformation for the context
shown, under ``world/policy``, redrawn when the context changes. Needs ``pip install 'ciflow[view]'`` (``rerun-sdk``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading

import numpy as np

from ciflow import _native, connection
from ciflow.arguments import positive_seconds

#: Samples with a context different from the previous one by more than this are logged
#: as context changes.
CONTEXT_CHANGE = 1e-9


def _rerun():
    try:
        import rerun
    except ImportError as error:
        raise SystemExit("ciflow.view needs Rerun: pip install 'ciflow[view]'") from error
    return rerun


def body_archetype(body: dict):
    """The Rerun archetype drawing one body of ``_native.Scenery.scene``."""
    rr = _rerun()
    color = [body["color"]]
    kind = body["kind"]
    if kind == "capsule":
        return rr.Capsules3D(lengths=[body["length"]], radii=[body["radius"]],
                             translations=[body["translation"]],
                             quaternions=[body["quaternion"]], colors=color, fill_mode="solid")
    if kind == "cylinder":
        # ciflow's cylinder stands on its base; Rerun's is centred.
        axis = _rotate(body["quaternion"], [0.0, 0.0, 1.0])
        centre = np.asarray(body["translation"]) + body["height"] / 2.0 * axis
        return rr.Cylinders3D(lengths=[body["height"]], radii=[body["radius"]], centers=[centre],
                              quaternions=[body["quaternion"]], colors=color, fill_mode="solid")
    if kind == "cuboid":
        return rr.Boxes3D(half_sizes=[body["half_extents"]], centers=[body["translation"]],
                          quaternions=[body["quaternion"]], colors=color, fill_mode="solid")
    if kind == "sphere":
        r = body["radius"]
        return rr.Ellipsoids3D(half_sizes=[[r, r, r]], centers=[body["centre"]], colors=color,
                               fill_mode="solid")
    if kind == "curve":
        points = list(body["points"])
        if body["closed"] and points:
            points.append(points[0])
        return rr.LineStrips3D([points], radii=[body["radius"]], colors=color)
    raise ValueError(f"unknown body kind `{kind}`")


def _rotate(quaternion, vector) -> np.ndarray:
    x, y, z, w = quaternion
    q = np.array([x, y, z])
    v = np.asarray(vector, dtype=float)
    return v + 2.0 * np.cross(q, np.cross(q, v) + w * v)


def log_field(recording, path: str, report: dict) -> None:
    """Logs a 2-D policy's figure data for one context (``_native.FlowField.at``) under
    ``path``: ``field`` (arrows, the longest one grid cell long), ``latent_grid`` (the
    image of the latent grid lines) and ``rollouts`` (noise-free), in the plane ``z = 0``."""
    rr = _rerun()
    (data,) = report["fields"]
    xs, ys = np.meshgrid(data["x"], data["y"])
    velocity = np.stack([np.asarray(data["velocity_x"]), np.asarray(data["velocity_y"])], -1)
    velocity = velocity.reshape(-1, 2)
    cell = min(np.diff(data["x"]).min(), np.diff(data["y"]).min())
    longest = np.nanmax(np.linalg.norm(velocity, axis=1))
    scale = cell / longest if longest > 0 else 0.0
    flat = lambda points: [[p[0], p[1], 0.0] for p in points]  # noqa: E731
    origins = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], -1)
    vectors = np.concatenate([velocity * scale, np.zeros((len(velocity), 1))], -1)
    recording.log(f"{path}/field", rr.Arrows3D(origins=origins, vectors=vectors,
                                               colors=[[90, 90, 200]]))
    recording.log(f"{path}/latent_grid", rr.LineStrips3D(
        [flat(line) for line in data["latent_grid"]], colors=[[170, 170, 170]]))
    recording.log(f"{path}/rollouts", rr.LineStrips3D(
        [flat(line) for line in data["rollouts"] if line], colors=[[31, 119, 180]]))


class UrdfModel:
    """A task arm's own link geometry from its URDF's ``<visual>`` elements, logged once
    by Rerun's URDF loader and posed per sample: each URDF joint's transform is the
    parent link's placement inverted times the child link's, both from ciflow's forward
    kinematics (``Scenery.frame_placements``), so locked joints and tools come out as the
    task's model has them. The document arrives as text (the session holds no path), so
    meshes load only where the URDF names them by absolute path."""

    def __init__(self, recording, root: str, document: str):
        from rerun.urdf import UrdfTree

        self.recording, self.root = recording, root
        # One path chunk: Rerun's loader takes the prefix as a single name.
        prefix = urdf_prefix(root)
        with tempfile.NamedTemporaryFile("w", suffix=".urdf", delete=False) as file:
            file.write(document)
        try:
            self.tree = UrdfTree.from_file_path(file.name, entity_path_prefix=prefix,
                                                frame_prefix=f"{prefix}/")
            self.tree.log_urdf_to_recording(recording)
        finally:
            os.unlink(file.name)
        self.frame_prefix = f"{prefix}/"
        # The URDF's root link is the task's base: hang its frame tree on the track's
        # world (an entity's implicit frame is `tf#/<entity path>`).
        recording.log(f"{root}/world/urdf_base", _rerun().Transform3D(
            translation=[0.0, 0.0, 0.0], parent_frame=f"tf#/{root}/world",
            child_frame=self.frame_prefix + self.tree.root_link().name), static=True)

    @classmethod
    def of(cls, recording, root: str, document) -> "UrdfModel | None":
        """The model of ``document`` (a URDF text), or None without one or without any
        ``<visual>`` (the task's capsules are drawn then)."""
        if not isinstance(document, str) or "<visual" not in document:
            return None
        return cls(recording, root, document)

    def pose(self, placements: dict) -> None:
        """Logs every joint of the URDF whose two links the task's arm has a frame for."""
        for joint in self.tree.joints():
            parent, child = placements.get(joint.parent_link), placements.get(joint.child_link)
            if parent is None or child is None:
                continue
            translation, quaternion = relative_pose(parent, child)
            self.recording.log(
                f"{self.root}/world/urdf_joints/{joint.name}",
                _rerun().Transform3D(translation=translation, quaternion=quaternion,
                                     parent_frame=self.frame_prefix + joint.parent_link,
                                     child_frame=self.frame_prefix + joint.child_link))


def urdf_prefix(root: str) -> str:
    """The one-chunk entity path under which the URDF model of track ``root`` lives."""
    return "urdf-" + root.replace("/", "-")


def relative_pose(parent, child) -> tuple[np.ndarray, np.ndarray]:
    """``parent⁻¹ · child`` of two placements ``(translation, quaternion xyzw)``."""
    (tp, qp), (tc, qc) = parent, child
    inverse = np.array([-qp[0], -qp[1], -qp[2], qp[3]])
    return _rotate(inverse, np.subtract(tc, tp)), _multiply(inverse, qc)


def _multiply(a, b) -> np.ndarray:
    """The quaternion product ``a b`` (xyzw)."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def send_layout(recording, roots: list[str]) -> None:
    """Lays the viewer out for the tracks at ``roots``: the 3-D scene on the left two
    thirds, the state, command and event log of every track stacked on the right."""
    import rerun.blueprint as rrb

    def series(name: str):
        return rrb.TimeSeriesView(name=name, contents=[f"+ /{root}/{name}" for root in roots])

    recording.send_blueprint(rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="/", contents=[
                f"+ /{path}/**" for root in roots for path in (f"{root}/world", urdf_prefix(root))]),
            rrb.Vertical(series("state"), series("command"),
                         rrb.TextLogView(name="events",
                                         contents=[f"+ /{root}/events" for root in roots])),
            column_shares=[2, 1]),
        collapse_panels=True))


class Track:
    """One session's or episode's entities in a recording, under ``root``. With a 2-D
    ``flow_field`` of the same task, the policy's field and latent-grid deformation are
    logged under ``world/policy`` for the first context and after each change."""

    def __init__(self, recording, root: str, task: str, kwargs: dict | None = None,
                 flow_field: _native.FlowField | None = None):
        self.rr = _rerun()
        self.recording = recording
        self.root = root.strip("/")
        self.scenery = _native.Scenery(task, kwargs or {})
        self.flow_field = flow_field
        self.urdf = UrdfModel.of(recording, self.root, (kwargs or {}).get("urdf"))
        self.previous_context = None
        self.samples = 0
        # Series whose line names are logged (once, static).
        self.named: set[str] = set()
        # Whether the last live sample was pushed (a push starts on a rising edge).
        self.pushed = False

    def log(self, time: float, observation, context_dim: int, command=None,
            reward: float | None = None) -> None:
        """Logs one observation (state then its ``context_dim`` context entries) at
        simulated ``time`` (s), with the command and reward that led to it, if any."""
        rr, rec = self.rr, self.recording
        observation = np.asarray(observation, dtype=float)
        rec.set_time("time", duration=float(time))
        for body in self.scenery.scene(observation.tolist()):
            if self.urdf is not None and body["name"].startswith("robot/"):
                continue  # the URDF's own link geometry stands in for the capsules
            rec.log(f"{self.root}/world/{body['name']}", body_archetype(body))
        if self.urdf is not None:
            self.urdf.pose(self.scenery.frame_placements(observation.tolist()))
        split = len(observation) - context_dim
        state, context = observation[:split], observation[split:]
        series = [("state", state), ("context", context)]
        if command is not None:
            series.append(("command", np.asarray(command, dtype=float)))
        if reward is not None:
            series.append(("reward", np.array([reward], dtype=float)))
        for name, values in series:
            if not len(values):
                continue
            path = f"{self.root}/{name}"
            if path not in self.named:
                names = [name] if len(values) == 1 else [f"{name}[{i}]" for i in range(len(values))]
                rec.log(path, rr.SeriesLines(names=names), static=True)
                self.named.add(path)
            rec.log(path, rr.Scalars(values))
        changed = (self.previous_context is not None and len(context)
                   and np.max(np.abs(context - self.previous_context)) > CONTEXT_CHANGE)
        if changed:
            self.event(f"context → {np.round(context, 4).tolist()}")
        if self.flow_field is not None and (changed or self.previous_context is None):
            report = json.loads(self.flow_field.at(context.tolist()))
            log_field(rec, f"{self.root}/world/policy", report)
        self.previous_context = context
        self.samples += 1

    def event(self, text: str, level: str = "INFO") -> None:
        """A line in the track's event log at the current time."""
        self.recording.log(f"{self.root}/events", self.rr.TextLog(text, level=level))


def open_recording(application: str, spawn: bool = False, serve: bool = False,
                   save: str | None = None):
    """A Rerun recording stream sent to a native viewer (``spawn``), a web viewer
    (``serve``; its URL is printed) and/or an ``.rrd`` file (``save``)."""
    rr = _rerun()
    recording = rr.RecordingStream(application)
    sinks = []
    if save:
        sinks.append(rr.FileSink(save))
    if spawn:
        recording.spawn(connect=False)
        sinks.append(rr.GrpcSink())
    if serve:
        url = recording.serve_grpc()
        rr.serve_web_viewer(connect_to=url, open_browser=False)
        print(f"Rerun web viewer serving {url}", flush=True)
        sinks.append(rr.GrpcSink(url))
    recording.set_sinks(*sinks)
    return recording


def _matching(flow_field: _native.FlowField | None, task: str) -> _native.FlowField | None:
    """``flow_field`` if it is a policy of ``task``; otherwise None, with a note."""
    if flow_field is None:
        return None
    from ciflow.registration import task_entry

    if task_entry(flow_field.task)[0] != task_entry(task)[0]:
        print(f"--policy is a policy of {flow_field.task}, not of {task}: no field drawn",
              file=sys.stderr)
        return None
    return flow_field


def finish(recording) -> None:
    """Sends everything logged and closes the sinks (an ``.rrd`` file is complete after
    this)."""
    recording.flush()
    recording.disconnect()


def record_run(recording, task: str, kwargs: dict, samples: list[dict], events: list[dict],
               root: str = "run", flow_field: _native.FlowField | None = None) -> Track:
    """Logs a perturbation run (``ciflow.perturb``'s samples and events) as one track."""
    track = Track(recording, root, task, kwargs, _matching(flow_field, task))
    send_layout(recording, [track.root])
    pending = sorted(events, key=lambda e: e["start"])
    for sample in samples:
        while pending and pending[0]["start"] <= sample["time"]:
            event = pending.pop(0)
            recording.set_time("time", duration=float(event["start"]))
            track.event(f"{event['kind']} for {event['duration']:.2f} s", level="WARN")
        observation = np.concatenate([sample["state"], sample["context"]])
        track.log(sample["time"], observation, len(sample["context"]), sample["command"],
                  sample["reward"])
    return track


def record_dataset(recording, path: str, episodes: slice | None = None,
                   flow_field: _native.FlowField | None = None) -> list[Track]:
    """Logs every episode of the dataset at ``path`` (or the slice ``episodes``) one after
    another on the ``time`` timeline, each under ``episodes/<k>``."""
    info, all_episodes = _native.read_dataset(path)
    dim, context_dim, action_dim = (len(info[f"{space}_space"]["low"])
                                    for space in ("observation", "context", "action"))
    dt = info["control_dt"]
    chosen = list(enumerate(all_episodes))[episodes or slice(None)]
    if not chosen:
        raise ValueError(f"episodes {episodes.start}:{episodes.stop} select none of the "
                         f"{len(all_episodes)} episodes of {path}")
    send_layout(recording, [f"episodes/{k}" for k, _ in chosen])
    tracks, offset = [], 0.0
    for k, episode in chosen:
        track = Track(recording, f"episodes/{k}", info["env_id"], info["env_kwargs"],
                      _matching(flow_field, info["env_id"]))
        observations = np.frombuffer(episode["observations"], dtype="<f8").reshape(-1, dim)
        actions = np.frombuffer(episode["actions"], dtype="<f8").reshape(-1, action_dim)
        rewards = np.frombuffer(episode["rewards"], dtype="<f8")
        perturbed = episode["infos"].get("perturbed")
        perturbed = None if perturbed is None else np.frombuffer(perturbed, dtype="<f8")
        for step, observation in enumerate(observations):
            command = actions[step - 1] if step > 0 else None
            reward = rewards[step - 1] if step > 0 else None
            track.log(offset + step * dt, observation, context_dim, command, reward)
            if perturbed is not None and step < len(perturbed) and perturbed[step] > 0 and (
                    step == 0 or perturbed[step - 1] == 0):
                track.event("push", level="WARN")
        track.event(f"episode {k} (seed {episode['seed']}) ends")
        offset += len(observations) * dt
        tracks.append(track)
    return tracks


def watch(recording, client: _native.ClientHandle, engine: str | None, session: str | None,
          timeout: float | None, max_samples: int | None = None,
          flow_field: _native.FlowField | None = None) -> dict[str, Track]:
    """Logs the telemetry of every session on ``engine`` (or only ``session``) as it
    arrives, each under ``sessions/<id>``, until ``timeout`` seconds pass without a sample
    or ``max_samples`` arrive. Returns the tracks by session id."""
    feed = client.watch(engine)
    tracks: dict[str, Track] = {}
    skipped: set[str] = set()
    received = 0
    while max_samples is None or received < max_samples:
        sample = feed.recv(timeout)
        if sample is None:
            break
        if session is not None and sample["session"] != session:
            continue
        if sample["session"] in skipped:
            continue
        track = tracks.get(sample["session"])
        if track is None:
            try:
                described = client.describe(sample["engine"], sample["identity"],
                                            sample["session"])
                track = Track(recording, f"sessions/{sample['session']}", described["task"],
                              described["kwargs"], _matching(flow_field, described["task"]))
            except (_native.CiflowError, ValueError) as error:
                # Closed since its sample was sent, or a task this build does not know.
                print(f"not showing session {sample['session']}: {error}", file=sys.stderr)
                skipped.add(sample["session"])
                continue
            tracks[sample["session"]] = track
            send_layout(recording, [t.root for t in tracks.values()])
            print(f"watching session {sample['session']} ({described['task']}) of "
                  f"{sample['identity']} on {sample['engine']}", flush=True)
        state, context, command = (np.frombuffer(sample[k], dtype="<f8")
                                   for k in ("state", "context", "command"))
        track.log(sample["time"], np.concatenate([state, context]), len(context), command,
                  sample["reward"])
        if sample["perturbed"] and not track.pushed:
            track.event("push", level="WARN")
        track.pushed = sample["perturbed"]
        if sample["episode_done"]:
            track.event("episode ends")
        received += 1
    return tracks


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ciflow.view", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--watch", metavar="ENGINE",
                        help="watch every session of this engine ('*': every engine)")
    source.add_argument("--dataset", help="show every episode of this dataset directory")
    source.add_argument("--record", help="show a run recorded by ciflow.perturb --record")
    parser.add_argument("--session", help="with --watch: only this session id")
    parser.add_argument("--episodes", type=_episode_slice,
                        help="with --dataset: episode K, or the slice of episodes A:B (either "
                             "end may be left out), e.g. 0:10")
    parser.add_argument("--engine", help="endpoint to connect to, e.g. tcp/10.0.0.5:7447")
    parser.add_argument("--zenoh-config", help="Zenoh JSON5 file (e.g. via a router)")
    parser.add_argument("--policy", metavar="CHECKPOINT",
                        help="a 2-D flow policy's checkpoint directory: draw its vector field "
                             "and latent-grid deformation for each context shown")
    parser.add_argument("--timeout", type=positive_seconds, default=None,
                        help="with --watch: stop after this many seconds without telemetry")
    parser.add_argument("--spawn", action="store_true", help="start a native viewer (default)")
    parser.add_argument("--serve", action="store_true", help="serve a web viewer")
    parser.add_argument("--save", metavar="FILE.rrd", help="write a recording")
    args = parser.parse_args(argv)
    try:
        return _view(parser, args)
    except (OSError, ValueError, RuntimeError, _native.CiflowError,
            _native.EngineUnreachable) as error:
        print(f"ciflow.view: error: {error}", file=sys.stderr)
        return 2


def _episode_slice(text: str) -> slice:
    """``K`` (episode K) or ``A:B`` (argparse type): indices from 0, neither negative."""
    start, colon, stop = text.partition(":")
    invalid = argparse.ArgumentTypeError(f"`{text}` is neither an episode K nor a slice A:B "
                                         "of episode numbers (from 0)")
    try:
        bounds = [int(b) if b.strip() else None for b in (start, stop)]
    except ValueError:
        raise invalid from None
    if any(b is not None and b < 0 for b in bounds):
        raise invalid
    if not colon:
        if bounds[0] is None:
            raise argparse.ArgumentTypeError("an empty --episodes selects nothing")
        return slice(bounds[0], bounds[0] + 1)
    return slice(*bounds)


def _view(parser, args) -> int:
    spawn = args.spawn or not (args.serve or args.save)
    recording = open_recording("ciflow", spawn=spawn, serve=args.serve, save=args.save)
    flow_field = _native.FlowField(args.policy) if args.policy else None
    if args.dataset:
        tracks = record_dataset(recording, args.dataset, args.episodes, flow_field)
        print(f"{len(tracks)} episode(s) of {args.dataset}")
    elif args.record:
        with open(args.record) as file:
            record = json.load(file)
        if not isinstance(record, dict) or "samples" not in record:
            raise ValueError(f"{args.record} is not a run recorded by ciflow.perturb --record "
                             "(no `samples`)")
        if not record.get("task"):
            parser.error(f"{args.record} names no task (an older ciflow.perturb, or one "
                         "whose engine did not say)")
        samples = [{k: np.asarray(v) if isinstance(v, list) else v for k, v in s.items()}
                   for s in record["samples"]]
        track = record_run(recording, record["task"], record.get("kwargs", {}), samples,
                           record.get("events", []), flow_field=flow_field)
        print(f"{track.samples} samples of {args.record}")
    else:
        client = connection.client(args.engine, args.zenoh_config)
        engine = None if args.watch == "*" else args.watch
        if engine is not None:
            client.engine_info(engine)  # an engine that does not answer is an error
        try:
            tracks = watch(recording, client, engine, args.session, args.timeout,
                           flow_field=flow_field)
        except KeyboardInterrupt:
            tracks = {}
        print(f"watched {len(tracks)} session(s)")
    if args.serve and not args.watch:
        print("serving the recording; Ctrl-C to stop", flush=True)
        try:
            threading.Event().wait()
        except KeyboardInterrupt:
            pass
    finish(recording)
    return 0


if __name__ == "__main__":
    sys.exit(main())
