"""Controlling a running session from any process: ``ciflow.attach(session, token)``.

The session's owner shares its id and token (``env.unwrapped.session_id`` and
``env.unwrapped.token_hex``); the attached process can then start or stop a policy run,
push the robot, change the context and read the telemetry while the owner keeps the
session. This module speaks bridge/PROTOCOL.md directly with ``eclipse-zenoh`` and
``msgpack``, so it works against any engine, across machines through a Zenoh router.
"""

from __future__ import annotations

import os
import queue

import msgpack
import numpy as np
import zenoh

from ciflow import _native
from ciflow.connection import _looks_like_endpoint, default_endpoint

VERSION = _native.PROTOCOL_VERSION
_F64_FIELDS = ("state", "command", "context")


def _f64s(values) -> bytes:
    return np.asarray(values, dtype="<f8").tobytes()


def _open_zenoh(engine: str | None, zenoh_config: str | None) -> zenoh.Session:
    zenoh_config = zenoh_config or os.environ.get("CIFLOW_ZENOH_CONFIG") or None
    engine = engine or os.environ.get("CIFLOW_ENGINE") or None
    if zenoh_config:
        config = zenoh.Config.from_file(zenoh_config)
    else:
        config = zenoh.Config()
        config.insert_json5("mode", '"client"')
        config.insert_json5("scouting/multicast/enabled", "false")
    if engine and _looks_like_endpoint(engine):
        config.insert_json5("connect/endpoints", f'["{engine}"]')
    elif not zenoh_config:
        config.insert_json5("connect/endpoints", f'["{default_endpoint()}"]')
    return zenoh.open(config)


class Attached:
    """Control of one session held by another process (or this one). Methods mirror the
    session operations; each is one query answered by exactly one reply."""

    def __init__(
        self,
        session: str,
        token: str | bytes,
        engine: str | None = None,
        engine_name: str | None = None,
        zenoh_config: str | None = None,
        timeout: float = 10.0,
    ):
        self.session = session
        self.token = bytes.fromhex(token) if isinstance(token, str) else bytes(token)
        # Without the engine's name, a wildcard reaches whichever engine holds the session.
        self.engine_name = engine_name or "*"
        self.timeout = timeout
        self._zenoh = _open_zenoh(engine, zenoh_config)

    def _key(self, leaf: str) -> str:
        return f"ciflow/v1/engine/{self.engine_name}/session/{self.session}/{leaf}"

    def _call(self, op: str, **fields) -> dict:
        request = {"v": VERSION, "token": self.token, **fields}
        replies = self._zenoh.get(
            self._key(op),
            payload=msgpack.packb(request, use_bin_type=True),
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=self.timeout,
        )
        errors = []
        for reply in replies:
            if reply.ok is not None:
                return msgpack.unpackb(reply.ok.payload.to_bytes(), raw=False)
            errors.append(msgpack.unpackb(reply.err.payload.to_bytes(), raw=False))
        # Through a wildcard, engines without the session answer `unknown_session`.
        errors.sort(key=lambda e: e.get("code") == "unknown_session")
        if errors:
            error = _native.CiflowError(f"{errors[0]['code']}: {errors[0]['message']}")
            error.code = errors[0]["code"]
            raise error
        raise _native.EngineUnreachable(f"no ciflow engine answered on {self._key(op)}")

    def run_policy(self, policy: str, speed: float = 1.0, steps: int | None = None,
                   index: int = 0) -> float:
        """Lets the engine step the session with ``policy``'s action once per control
        period, at ``speed`` × real time (0: as fast as possible), for ``steps`` steps or
        until the episode ends. Returns the simulated time at the start."""
        fields = {"index": int(index), "policy": policy, "speed": float(speed)}
        if steps is not None:
            fields["steps"] = int(steps)
        return self._call("run", **fields)["time"]

    def stop(self) -> float:
        """Stops the policy run (no effect without one)."""
        return self._call("stop")["time"]

    def perturb(self, perturbation: dict, index: int = 0) -> float:
        """Schedules ``{"kind": "joint_torque", "torque": [...], "start"?, "duration"}`` or
        ``{"kind": "link_wrench", "link", "force", "torque", "start"?, "duration"}``
        (``start`` in simulated seconds since the reset; absent: now)."""
        message = {k: v for k, v in perturbation.items() if v is not None}
        return self._call("perturb", index=int(index), perturbation=message)["time"]

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
        return self._call("context", index=int(index), context=_f64s(context))["time"]

    def telemetry(self, timeout: float | None = None):
        """A :class:`TelemetryFeed` of this session's samples (subscribe before starting
        what you want to record)."""
        return TelemetryFeed(self._zenoh, self._key("telemetry"), timeout)

    def close(self) -> None:
        """Leaves Zenoh (the session stays with its owner)."""
        self._zenoh.close()


class TelemetryFeed:
    """Telemetry samples as dicts (``state``, ``command``, ``context`` as numpy arrays;
    ``step``, ``time``, ``reward``, ``running``, ``episode_done``). Iterate it, or
    :meth:`get` one sample; iteration ends after ``timeout`` seconds without a sample."""

    def __init__(self, zsession: zenoh.Session, key: str, timeout: float | None):
        self._samples: queue.Queue = queue.Queue()
        self._timeout = timeout
        self._subscriber = zsession.declare_subscriber(key, self._receive)

    def _receive(self, sample) -> None:
        message = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        for field in _F64_FIELDS:
            message[field] = np.frombuffer(message[field], dtype="<f8").copy()
        self._samples.put(message)

    def get(self, timeout: float | None = None) -> dict | None:
        try:
            return self._samples.get(timeout=timeout)
        except queue.Empty:
            return None

    def __iter__(self):
        while (sample := self.get(self._timeout)) is not None:
            yield sample

    def close(self) -> None:
        self._subscriber.undeclare()


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
    return Attached(session, token, engine, engine_name, zenoh_config)
