"""``gymnasium.vector.VectorEnv`` over the engines' batched step: one request per engine
steps all of that engine's environments, the requests to different engines in flight
together (sent by the native client before it waits for any reply)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from ciflow import _native, connection
from ciflow.spaces import (
    actions_to_wire, box, construction_kwargs, from_wire, reset_options, seed_value,
)


class CiflowVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of a task, stepped by one request per engine.

    ``engines`` spreads them over several engines — a list of engine names, or ``"*"``
    for every engine serving the task that ``engine``/``zenoh_config`` reaches (e.g. a
    Zenoh router joining machines), in name order. Environment ``i`` lives on the engine
    whose share holds ``i`` (shares differ by at most one, in the order of ``engines``);
    each step sends every engine its share at once and merges the replies in that fixed
    order, so results do not depend on which engine answers first. An engine that stops
    answering raises ``EngineUnreachable`` (or ``CiflowError``) after the client's
    timeout.

    Autoreset is Gymnasium's next-step mode (``metadata["autoreset_mode"]``): after an
    episode ends, the next ``step`` ignores that environment's action, resets it and
    returns its first observation with reward 0 and both flags false. Environment ``i`` of
    ``reset(seed=s)`` is seeded with ``s + i``, of ``reset(seed=[...])`` with entry ``i``.
    Infos hold one array per key, with a boolean ``_key`` mask of the environments that
    reported it.

    ``context``, ``initial_position`` and ``initial_velocity`` (as keyword arguments or
    reset options) are one value for every environment, or an array of ``num_envs`` rows,
    one per environment: environment ``i`` then resets, and autoresets, with row ``i``.
    Actions have the shape of ``action_space``, ``(num_envs,) + single_action_space.shape``.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        task: str,
        context=None,
        engine: str | None = None,
        zenoh_config: str | None = None,
        render_mode: str | None = None,
        max_episode_steps: int | None = None,
        initial_position=None,
        initial_velocity=None,
        engines: list[str] | str | None = None,
        **kwargs,
    ):
        if render_mode is not None:
            raise ValueError("CiflowVectorEnv does not render; use gymnasium.make for frames")
        self._sessions = []
        if isinstance(num_envs, bool) or int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a whole number of at least 1, not {num_envs!r}")
        num_envs = int(num_envs)
        if engines is None:
            client, engine_name = connection.resolve(task, engine, zenoh_config)
            names = [engine_name]
        else:
            client, names = connection.resolve_engines(task, engines, engine, zenoh_config)
        shares = [num_envs // len(names) + (k < num_envs % len(names))
                  for k in range(len(names))]
        construction = construction_kwargs(task, kwargs)
        for name, share in zip(names, shares):
            if share > 0:
                self._sessions.append(client.make(name, task, share, construction))
        self.engine_names = [s.engine for s in self._sessions]
        self._shares = [s.num_envs for s in self._sessions]
        spec = self._sessions[0].spec
        self.task_spec = spec
        self.num_envs = num_envs
        self.single_observation_space = box(spec["observation_space"])
        self.single_action_space = box(spec["action_space"])
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._obs_shape = (self.num_envs, self.single_observation_space.shape[0])
        self._reset_defaults = {
            "context": context,
            "initial_position": initial_position,
            "initial_velocity": initial_velocity,
        }
        self.render_mode = None

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Resets every environment: with ``seed=s`` environment ``i`` gets ``s + i``; with
        a list, its entry ``i`` (``None``: that environment's RNG continues), as
        Gymnasium's ``SyncVectorEnv``."""
        seeds = None
        if isinstance(seed, (list, tuple, np.ndarray)):
            seeds = [None if s is None else seed_value(s) for s in seed]
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
            seed = None
        else:
            seed = None if seed is None else seed_value(seed)
            super().reset(seed=seed)
        options = reset_options(self._reset_defaults, options)
        observations, info = _native.reset_batches(self._sessions, seed, options, seeds)
        return self._observations(observations), self._info(info)

    def step(self, actions):
        actions = actions_to_wire(actions, self.action_space.shape,
                                  "num_envs, action dimension")
        observations, rewards, terminated, truncated, info = _native.step_batches(
            self._sessions, actions)
        # The engine's bytearrays become the arrays, writable and without a copy.
        return (
            self._observations(observations),
            np.frombuffer(rewards, dtype="<f8"),
            np.frombuffer(terminated, dtype=np.bool_),
            np.frombuffer(truncated, dtype=np.bool_),
            self._info(info),
        )

    def _observations(self, data: bytes) -> np.ndarray:
        return from_wire(data, self.single_observation_space.dtype, self._obs_shape)

    @staticmethod
    def _info(columns: dict) -> dict:
        """One array per key (NaN where an environment did not report it) and its ``_key``
        mask."""
        info = {}
        for key in sorted(columns):
            values = np.frombuffer(columns[key], dtype="<f8")
            info[key] = values
            info[f"_{key}"] = ~np.isnan(values)
        return info

    def close_extras(self, **kwargs):
        for session in self._sessions:
            try:
                session.close()
            except _native.EngineUnreachable:
                pass  # the engine is gone, and its sessions with it
