"""A served policy called from any control loop, without Gymnasium:
``ciflow.Policy("pour", engine="tcp/10.0.0.5:7447").act(observation)``.

The engine (``ciflow serve --policy NAME=DIR``) evaluates the policy; each ``act`` is one
Zenoh query answered by one reply, so it costs one network round trip plus the policy's
evaluation. ``python_client/examples/control_loop.py`` runs it at 1 kHz.
"""

from __future__ import annotations

import numpy as np

from ciflow import _native, connection


class Policy:
    """A policy an engine serves. ``observation`` is ``[q, q̇, c]`` of the policy's task
    (one row, or a batch of rows); ``act`` returns the desired accelerations ``q̈_des``."""

    def __init__(self, name: str, engine: str | None = None, zenoh_config: str | None = None):
        self.name = name
        self._client = connection.client(engine, zenoh_config)
        wanted = engine if engine and not connection._looks_like_endpoint(engine) else None
        for info in self._client.discover():
            if wanted not in (None, info["name"]):
                continue
            served = next((p for p in info["policies"] if p["name"] == name), None)
            if served is not None:
                break
        else:
            raise _native.EngineUnreachable(
                f"no engine reachable via {engine or 'the default endpoint'} serves a policy "
                f"named {name!r}; serve one with `ciflow serve --policy {name}=DIR`"
            )
        self.engine: str = info["name"]
        self.task: str = served["task"]
        self.observation_dim: int = served["observation_dim"]
        self.action_dim: int = served["action_dim"]

    def act(self, observation) -> np.ndarray:
        """``q̈_des`` for one observation (shape ``(observation_dim,)``) or a batch
        (``(n, observation_dim)``); the result has the same leading shape, and is the
        caller's own (writable) array."""
        rows = np.ascontiguousarray(observation, dtype=np.float64)
        if rows.ndim not in (1, 2) or rows.shape[-1] != self.observation_dim:
            raise ValueError(
                f"observation of shape {rows.shape}: ({self.observation_dim},) or "
                f"(n, {self.observation_dim}) expected for {self.task}"
            )
        reply = self._client.act(self.engine, self.name, rows.tobytes())
        return np.frombuffer(reply, dtype="<f8").reshape(rows.shape[:-1] + (self.action_dim,))
