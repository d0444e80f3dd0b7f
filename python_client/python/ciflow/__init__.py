"""ciflow: provably stable learned robot motions as Gymnasium environments over Zenoh.

``import ciflow`` registers the tasks with Gymnasium::

    import gymnasium as gym
    import ciflow

    # context: the pot pose (x, y, z in m; roll, pitch, yaw in rad)
    env = gym.make("ciflow/Pouring-v0", context=[0.5, 0.0, 0.05, 0.0, 0.0, 0.3], render_mode="rgb_array")
    envs = gym.make_vec("ciflow/LimitCycle-v0", num_envs=1024)   # one request per step
    # spread over every engine behind a router, one request per engine per step
    envs = gym.make_vec("ciflow/LimitCycle-v0", num_envs=8192, engine="tcp/R:7447", engines="*")

The environments live in an engine. ``engine=`` (or ``CIFLOW_ENGINE``) selects one:
an endpoint such as ``"tcp/10.0.0.5:7447"`` or an engine name. Without it, the engine on
``tcp/127.0.0.1:7447`` is used, and if none runs there, one is started inside this
process and announced on Zenoh so that other processes can reach its sessions.
``zenoh_config=`` (or ``CIFLOW_ZENOH_CONFIG``) points at a standard Zenoh JSON5 file.

A served policy can also be called from any control loop, without Gymnasium::

    policy = ciflow.Policy("pour", engine="tcp/10.0.0.5:7447")
    qdd_des = policy.act(np.concatenate([q, qd, context]))
"""

from ciflow._native import (
    DEFAULT_ENDPOINT,
    PROTOCOL_VERSION,
    CiflowError,
    EngineUnreachable,
)
from ciflow.connection import discover, shutdown_embedded_engine
from ciflow.env import CiflowEnv
from ciflow.policy import Policy
from ciflow.registration import TASK_IDS, register_tasks
from ciflow.remote import Attached, attach
from ciflow.vector import CiflowVectorEnv

__all__ = [
    "Attached",
    "DEFAULT_ENDPOINT",
    "PROTOCOL_VERSION",
    "TASK_IDS",
    "CiflowEnv",
    "CiflowError",
    "CiflowVectorEnv",
    "EngineUnreachable",
    "Policy",
    "attach",
    "discover",
    "register_tasks",
    "shutdown_embedded_engine",
]

register_tasks()
