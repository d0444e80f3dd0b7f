"""Controlling a running session from any process: ``ciflow.attach(session, token)``.

The session's owner shares its id and token (``env.unwrapped.session_id`` and
``env.unwrapped.token_hex``); the attached process can then start or stop a policy run,
push the robot, change the context and read the telemetry while the owner keeps the
session. Every request goes through the native client (``ciflow._native``), the same
one the environments use, so it works against any engine, across machines through a
Zenoh router.
"""

from __future__ import annotations

import os

import numpy as np

from ciflow import _native, connection

_F64_FIELDS = ("state", "command", "context")


class Attached:
    """The controls of one session, held by its owner or by another process. Each method
    is one query answered by exactly one reply."""

    def __init__(self, control: _native.Control):
        self._control = control

    @property
    def session(self) -> str:
        return self._control.session_id

    @property
    def engine_name(self) -> str:
        """The engine's name, or ``*`` when attached to whichever engine holds it."""
        return self._control.engine

    def run_policy(self, policy: str, speed: float = 1.0, steps: int | None = None,
                   index: int = 0) -> float:
        """Lets the engine step the session with ``policy``'s action once per control
        period, at ``speed`` × real time (0: as fast as possible), for ``steps`` steps or
        until the episode ends. Returns the simulated time at the start."""
        return self._control.run(policy, float(speed), steps, int(index))

    def stop(self) -> float:
        """Stops the policy run (no effect without one)."""
        return self._control.stop()

    def perturb(self, perturbation: dict, index: int = 0) -> float:
        """Schedules ``{"kind": "joint_torque", "torque": [...], "start"?, "duration"}`` or
        ``{"kind": "link_wrench", "link", "force", "torque"?, "start"?, "duration"}``
        (``start`` in simulated seconds since the reset; absent: now)."""
        return self._control.perturb(perturbation, int(index))

    def push_joint_torque(self, torque, duration: float, start: float | None = None) -> float:
        return self.perturb({"kind": "joint_torque", "torque": [float(t) for t in torque],
                             "start": start, "duration": float(duration)})

    def push_link_wrench(self, link: int, force, torque=(0.0, 0.0, 0.0), duration: float = 0.1,
                         start: float | None = None) -> float:
        return self.perturb({
            "kind": "link_wrench", "link": int(link), "force": [float(f) for f in force],
            "torque": [float(t) for t in torque], "start": start, "duration": float(duration),
        })

    def set_context(self, context, index: int = 0) -> float:
        """Replaces the context now; returns the simulated time it took effect."""
        return self._control.set_context(np.asarray(context, dtype="<f8").tobytes(), int(index))

    def check_context(self, context, index: int = 0) -> str | None:
        """Whether the task accepts ``context`` (as a reset option or in
        :meth:`set_context`), changing nothing: ``None`` if it does, else the reason."""
        return self._control.check_context(np.asarray(context, dtype="<f8").tobytes(), int(index))

    def telemetry(self, timeout: float | None = None) -> TelemetryFeed:
        """A :class:`TelemetryFeed` of this session's samples (subscribe before starting
        what you want to record)."""
        return TelemetryFeed(self._control.telemetry(), timeout)

    def close(self) -> None:
        """Lets go of the controls (the session stays with its owner)."""


class TelemetryFeed:
    """Telemetry samples as dicts (``state``, ``command``, ``context`` as numpy arrays;
    ``step``, ``time``, ``reward``, ``running``, ``episode_done``). Iterate it, or
    :meth:`get` one sample; iteration ends after ``timeout`` seconds without a sample."""

    def __init__(self, feed: _native.TelemetryFeed, timeout: float | None):
        self._feed = feed
        self._timeout = timeout

    def get(self, timeout: float | None = None) -> dict | None:
        sample = self._feed.recv(timeout)
        if sample is not None:
            for field in _F64_FIELDS:
                sample[field] = np.frombuffer(sample[field], dtype="<f8").copy()
        return sample

    def __iter__(self):
        while (sample := self.get(self._timeout)) is not None:
            yield sample

    def close(self) -> None:
        self._feed = None


def attach(
    session: str,
    token: str | bytes,
    engine: str | None = None,
    engine_name: str | None = None,
    zenoh_config: str | None = None,
) -> Attached:
    """Attaches to session ``session`` with its hex (or bytes) ``token``.

    ``engine`` is an endpoint to connect to (default: ``CIFLOW_ENGINE``, else the local
    default endpoint); ``engine_name`` the engine's name (default: whichever engine holds
    the session); ``zenoh_config`` a Zenoh JSON5 file (e.g. to go through a router).
    """
    if isinstance(token, str):
        try:
            token = bytes.fromhex(token)
        except ValueError:
            raise ValueError(
                f"token {token!r} is not hexadecimal: give the token_hex the session's "
                "owner printed (env.unwrapped.token_hex)"
            ) from None
    else:
        token = bytes(token)
    client = connection.client(engine or os.environ.get("CIFLOW_ENGINE") or None,
                               zenoh_config or os.environ.get("CIFLOW_ZENOH_CONFIG") or None)
    return Attached(client.attach(session, token, engine_name))
