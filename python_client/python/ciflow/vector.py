"""``gymnasium.vector.VectorEnv`` over the engine's batched step: one request steps all
``num_envs`` environments."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from ciflow import connection
from ciflow.spaces import box, construction_kwargs, from_wire, reset_options, to_wire


class CiflowVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of a task in one engine session, stepped by one request.

    Autoreset is Gymnasium's next-step mode (``metadata["autoreset_mode"]``): after an
    episode ends, the next ``step`` ignores that environment's action, resets it and
    returns its first observation with reward 0 and both flags false. Environment ``i`` of
    ``reset(seed=s)`` is seeded with ``s + i``. Infos hold one array per key, with a
    boolean ``_key`` mask of the environments that reported it.
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
        **kwargs,
    ):
        if render_mode is not None:
            raise ValueError("CiflowVectorEnv does not render; use gymnasium.make for frames")
        self._session = None
        client, engine_name = connection.resolve(task, engine, zenoh_config)
        self._session = client.make(engine_name, task, int(num_envs), construction_kwargs(task, kwargs))
        spec = self._session.spec
        self.task_spec = spec
        self.num_envs = int(num_envs)
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

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if isinstance(seed, (list, tuple)):
            raise ValueError("pass one integer seed; environment i gets seed + i")
        observations, info = self._session.reset_batch(
            seed, reset_options(self._reset_defaults, options)
        )
        return self._observations(observations), self._info(info)

    def step(self, actions):
        actions = np.asarray(actions, dtype="<f8").reshape(self.num_envs, -1)
        observations, rewards, terminated, truncated, info = self._session.step_batch(
            to_wire(actions)
        )
        return (
            self._observations(observations),
            np.frombuffer(rewards, dtype="<f8").copy(),
            np.frombuffer(terminated, dtype=np.uint8).astype(bool),
            np.frombuffer(truncated, dtype=np.uint8).astype(bool),
            self._info(info),
        )

    def _observations(self, data: bytes) -> np.ndarray:
        return from_wire(data, self.single_observation_space.dtype, self._obs_shape)

    @staticmethod
    def _info(columns: dict) -> dict:
        info = {}
        for key, data in columns.items():
            values = np.frombuffer(data, dtype="<f8").copy()
            info[key] = values
            info[f"_{key}"] = ~np.isnan(values)
        return info

    def close_extras(self, **kwargs):
        if self._session is not None:
            self._session.close()
