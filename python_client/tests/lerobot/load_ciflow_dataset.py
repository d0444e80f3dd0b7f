"""Loads a LeRobot dataset that ciflow wrote (``python -m ciflow.convert --to-lerobot``)
with ``lerobot``'s own ``LeRobotDataset`` and checks every frame against the parquet
data: compatibility shown by LeRobot itself. Runs in LeRobot's environment
(``scripts/lerobot-env.sh``)::

    .venv-lerobot/bin/python python_client/tests/lerobot/load_ciflow_dataset.py DIR

Prints one JSON line: episodes, frames, fps and the features LeRobot sees; exits 1 on a
mismatch.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from lerobot.datasets.lerobot_dataset import LeRobotDataset

CHECKED = ("observation.state", "observation.velocity", "observation.environment_state",
           "action", "next.reward", "episode_index", "frame_index")


def main(root: Path) -> int:
    dataset = LeRobotDataset("ciflow/check", root=root)
    table = pq.read_table(sorted((root / "data").glob("**/*.parquet"))[0]).to_pydict()
    mismatches = 0
    for index in range(len(dataset)):
        frame = dataset[index]
        for name in CHECKED:
            got = np.asarray(frame[name].numpy(), dtype=np.float64).reshape(-1)
            want = np.asarray(table[name][index], dtype=np.float64).reshape(-1)
            if not np.array_equal(got, want):
                mismatches += 1
                print(f"frame {index}: {name} {got} != {want}", file=sys.stderr)
    print(json.dumps({
        "episodes": dataset.num_episodes, "frames": dataset.num_frames, "fps": dataset.fps,
        "features": sorted(dataset.features), "task": dataset[0]["task"],
        "mismatches": mismatches,
    }))
    return 1 if mismatches else 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
