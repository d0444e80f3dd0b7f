"""The plain-Python loop: a ciflow task through Gymnasium, the expert acting, one push.

    python python_client/examples/gym_loop.py [ENGINE]

ENGINE is an endpoint such as ``tcp/127.0.0.1:7447`` or an engine name; without it,
the engine on the default endpoint is used, or one is started inside this process.
"""

import sys

import gymnasium as gym
import numpy as np

import ciflow  # noqa: F401  (registers the ciflow/... ids with Gymnasium)


def main(engine: str | None = None) -> None:
    kwargs = {"engine": engine} if engine else {}
    env = gym.make("ciflow/Obstacle-v0", **kwargs)
    observation, info = env.reset(seed=0)
    start = observation[:2].copy()
    total_reward, steps = 0.0, 0
    while True:
        if steps == 20:
            # 3 N along y on the point mass for 0.2 s, from now on.
            env.unwrapped.perturb_link_wrench(link=0, force=(0.0, 3.0, 0.0), duration=0.2)
        action = env.unwrapped.expert_action()
        observation, reward, terminated, truncated, info = env.step(action)
        total_reward += reward
        steps += 1
        if terminated or truncated:
            break
    moved = float(np.linalg.norm(observation[:2] - start))
    print(f"{steps} steps, return {total_reward:.3f}, success {info['is_success'] == 1.0}, "
          f"moved {moved:.3f} m")
    env.close()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
