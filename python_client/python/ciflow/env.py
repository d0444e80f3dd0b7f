"""``gymnasium.Env`` for one ciflow task hosted by an engine."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from ciflow import connection
from ciflow.spaces import (
    actions_to_wire, box, construction_kwargs, from_wire, reset_options, seed_value,
)


class CiflowEnv(gym.Env):
    """A ciflow task stepped by an engine over Zenoh, one request per ``step``.

    Arguments:
        task: Gymnasium id or short name of the task.
        context: the context ``c`` for every reset (default: drawn by the task).
        render_mode: ``None`` or ``"rgb_array"``.
        engine: an endpoint (``"tcp/host:7447"``) or an engine name; default: the
            ``CIFLOW_ENGINE`` variable, else the local engine (started in-process if none).
        zenoh_config: a Zenoh JSON5 file (default: ``CIFLOW_ZENOH_CONFIG``).
        width, height: size of rendered frames.
        initial_position, initial_velocity: reset defaults (default: drawn by the task).
        **kwargs: the task's numeric construction arguments (e.g. ``obstacles=2``).

    Observations are numpy arrays in the task's observation space (state then context);
    actions are desired accelerations. ``truncated`` is set by the task after
    ``max_episode_steps``. Extra methods: ``expert_action``, ``set_context``,
    ``perturb_joint_torque``, ``perturb_link_wrench``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        task: str,
        context=None,
        render_mode: str | None = None,
        engine: str | None = None,
        zenoh_config: str | None = None,
        width: int = 480,
        height: int = 480,
        initial_position=None,
        initial_velocity=None,
        **kwargs,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} is not supported; use 'rgb_array'")
        self._session = None
        self._control = None
        self.render_mode = render_mode
        client, engine_name = connection.resolve(task, engine, zenoh_config)
        self._session = client.make(engine_name, task, 1, construction_kwargs(task, kwargs))
        spec = self._session.spec
        self.task_spec = spec
        self.observation_space = box(spec["observation_space"])
        self.action_space = box(spec["action_space"])
        self.context_space = box(spec["context_space"])
        self.metadata = {**self.metadata, "render_fps": round(1.0 / spec["control_dt"])}
        self._reset_defaults = {
            "context": context,
            "initial_position": initial_position,
            "initial_velocity": initial_velocity,
        }
        self._size = (int(width), int(height))
        self._last_time = 0.0

    @property
    def session_id(self) -> str:
        """The ``<session>`` chunk of the session's keys (telemetry:
        ``ciflow/v2/engine/<engine>/session/<session>/telemetry``)."""
        return self._session.session_id

    @property
    def engine_name(self) -> str:
        return self._session.engine

    @property
    def token_hex(self) -> str:
        """The session's secret token, hex: with ``session_id`` it lets another process
        control this session (``ciflow.attach(session_id, token_hex)``)."""
        return self._session.token.hex()

    def attach(self):
        """This session's :class:`ciflow.remote.Attached` controls (run, stop, perturb,
        context, telemetry), made on first use."""
        if self._control is None:
            from ciflow.remote import Attached

            self._control = Attached(self._session.control())
        return self._control

    def run_policy(self, name: str, speed: float = 1.0, steps: int | None = None) -> float:
        """Lets the engine drive this session with its loaded policy ``name`` (reset
        first): one step per control period at ``speed`` × real time (0: as fast as
        possible), for ``steps`` steps or until the episode ends. ``step``/``reset`` raise
        ``busy`` meanwhile; ``perturb_*`` and ``set_context`` act on the running robot."""
        return self.attach().run_policy(name, speed, steps)

    def stop(self) -> float:
        """Stops a policy run; returns the simulated time."""
        return self.attach().stop()

    @property
    def sim_time(self) -> float:
        """Simulated seconds since the last reset."""
        return self._last_time

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        seed = None if seed is None else seed_value(seed)
        super().reset(seed=seed)
        observation, info = self._session.reset(
            seed, reset_options(self._reset_defaults, options)
        )
        self._last_time = 0.0
        return from_wire(observation, self.observation_space.dtype), dict(info)

    def step(self, action):
        observation, reward, terminated, truncated, info, time = self._session.step(
            actions_to_wire(action, self.action_space.shape, "the action dimension")
        )
        self._last_time = time
        info = dict(info)
        info["time"] = time
        return (
            from_wire(observation, self.observation_space.dtype),
            float(reward),
            bool(terminated),
            bool(truncated),
            info,
        )

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        width, height = self._size
        pixels = self._session.render(width, height)
        return np.frombuffer(pixels, dtype=np.uint8).reshape(height, width, 3).copy()

    def expert_action(self) -> np.ndarray:
        """The task expert's desired acceleration for the current state."""
        return from_wire(self._session.expert(), self.action_space.dtype)

    def set_context(self, context) -> float:
        """Replaces the context mid-episode; returns the simulated time it took effect."""
        return self.attach().set_context(context)

    def check_context(self, context) -> str | None:
        """``None`` if the task accepts ``context`` (the context space is a box; some tasks
        accept only part of it), else the reason. Nothing changes."""
        return self.attach().check_context(context)

    def perturb_joint_torque(self, torque, duration: float, start: float | None = None) -> float:
        """Adds joint torques during ``[start, start + duration)`` simulated seconds
        (``start`` default: now). Returns the simulated time of acceptance."""
        return self.attach().push_joint_torque(torque, duration, start)

    def perturb_link_wrench(
        self, link: int, force, torque=(0.0, 0.0, 0.0), duration: float = 0.1,
        start: float | None = None,
    ) -> float:
        """Applies a world-aligned wrench at movable link ``link``."""
        return self.attach().push_link_wrench(link, force, torque, duration, start)

    def close(self):
        if self._control is not None:
            self._control.close()
            self._control = None
        if self._session is not None:
            self._session.close()
        super().close()
