"""The README's screenshot of the Rerun viewer, taken without a display.

Records 3 s of the pouring expert (seed 0, the hand pushed at 1 s) with
`ciflow.view.record_run`, then has Rerun's own viewer draw it headless
(`rerun --headless --screenshot-to`) and scales the picture to `docs/viewer.png`.
Rerun renders through Vulkan; on a machine without a GPU, Mesa's software driver
(lavapipe: `apt-get install mesa-vulkan-drivers`) does it.

    .venv/bin/python scripts/viewer_screenshot.py
"""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import gymnasium as gym
from PIL import Image

import ciflow  # noqa: F401  (registers the environments)
from ciflow import view

ROOT = Path(__file__).resolve().parent.parent
PUSH = {"kind": "push", "start": 1.0, "duration": 0.2}


def record(path: Path) -> None:
    env = gym.make("ciflow/Pouring-v0")
    env.reset(seed=0)
    env.unwrapped.perturb_link_wrench(6, [0.0, 30.0, 0.0], duration=PUSH["duration"],
                                      start=PUSH["start"])
    samples = []
    for step in range(300):
        action = env.unwrapped.expert_action()
        observation, reward, terminated, truncated, _ = env.step(action)
        samples.append({"time": 0.01 * (step + 1), "state": observation[:14],
                        "context": observation[14:], "command": action, "reward": reward})
        if terminated or truncated:
            break
    env.close()
    recording = view.open_recording("ciflow", save=str(path))
    view.record_run(recording, "pouring", {}, samples, [PUSH])
    view.finish(recording)


def main() -> int:
    with tempfile.TemporaryDirectory() as scratch:
        rrd, shot = Path(scratch) / "pouring.rrd", Path(scratch) / "viewer.png"
        record(rrd)
        rerun = Path(sys.executable).with_name("rerun")
        environment = {**os.environ, "WGPU_BACKEND": "vulkan",
                       "XDG_RUNTIME_DIR": os.environ.get("XDG_RUNTIME_DIR", scratch)}
        subprocess.run([str(rerun), "--headless", "--screenshot-to", str(shot),
                        "--window-size", "1280x720", str(rrd)],
                       check=True, env=environment, capture_output=True, timeout=600)
        picture = Image.open(shot).convert("RGB")
        picture.resize((1280, 720), Image.LANCZOS).save(ROOT / "docs" / "viewer.png",
                                                        optimize=True)
    print(f"wrote {ROOT / 'docs' / 'viewer.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
