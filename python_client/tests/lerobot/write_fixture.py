"""Writes the LeRobot fixture the tests read (``python_client/tests/lerobot/fixture``) with
the ``lerobot`` package itself, so that reading it shows compatibility with LeRobot, not
ciflow agreeing with ciflow. Runs in LeRobot's own environment (``lerobot`` pins a torch
the project does not use): ``scripts/lerobot-env.sh``, then

    .venv-lerobot/bin/python python_client/tests/lerobot/write_fixture.py OUT

Three episodes of a 2-D point reaching a goal under a PD law, 25 frames at 20 fps:
``observation.state`` = [x, y, vx, vy] (float32, as LeRobot usually stores numbers),
``observation.goal`` = [gx, gy], ``action`` the commanded acceleration.
"""

import shutil
import sys
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

FPS = 20
FRAMES = 25
FEATURES = {
    "observation.state": {"dtype": "float32", "shape": (4,), "names": ["x", "y", "vx", "vy"]},
    "observation.goal": {"dtype": "float32", "shape": (2,), "names": ["gx", "gy"]},
    "action": {"dtype": "float32", "shape": (2,), "names": ["ax", "ay"]},
}


def main(out: Path) -> None:
    shutil.rmtree(out, ignore_errors=True)
    dataset = LeRobotDataset.create(
        repo_id="ciflow/pointreach-fixture", fps=FPS, features=FEATURES, root=out,
        robot_type="point2d", use_videos=False,
    )
    dt = 1.0 / FPS
    for episode in range(3):
        rng = np.random.default_rng(episode)
        x, v, goal = rng.uniform(-1, 1, 2), np.zeros(2), rng.uniform(-0.3, 0.3, 2)
        for _ in range(FRAMES):
            action = np.clip(16 * (goal - x) - 8 * v, -10, 10)
            dataset.add_frame({
                "observation.state": np.concatenate([x, v]).astype(np.float32),
                "observation.goal": goal.astype(np.float32),
                "action": action.astype(np.float32),
                "task": "reach the goal",
            })
            v = v + dt * action
            x = x + dt * v
        dataset.save_episode()
    dataset.finalize()


if __name__ == "__main__":
    main(Path(sys.argv[1]))
