"""The plain-Python example runs against an engine in another process and finishes its
episode."""

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "gym_loop.py"


def test_gym_loop_runs_an_episode_with_a_push(engine):
    endpoint, _ = engine
    result = subprocess.run(
        [sys.executable, str(EXAMPLE), endpoint], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert "success True" in result.stdout, result.stdout
