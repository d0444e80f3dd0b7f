"""The wheel that ``make python`` builds stands on its own: installed into an empty
virtual environment with only the dependencies the package declares, ``import ciflow``
and ``gymnasium.make`` work, with an engine embedded in the process."""

import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]

# Runs in the fresh environment: one episode step of a task served by an embedded engine.
SCRIPT = """
import gymnasium, ciflow
env = gymnasium.make("ciflow/LimitCycle-v0")
observation, _ = env.reset(seed=0)
env.step(env.action_space.sample())
env.close()
ciflow.shutdown_embedded_engine()
print("stepped", observation.shape)
"""


def built_wheel() -> pathlib.Path:
    wheels = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target")) / "wheels"
    found = sorted(wheels.glob("ciflow-*.whl"))
    assert len(found) == 1, f"expected the one wheel `make python` builds in {wheels}: {found}"
    return found[0]


def test_the_wheel_installs_and_runs_in_an_empty_environment(tmp_path, private_default_endpoint):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    python = venv / "bin" / "python"
    install = subprocess.run([python, "-m", "pip", "install", "-q", built_wheel()],
                             capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr
    # Outside the repository, so nothing of it is importable but the installed package.
    run = subprocess.run([python, "-c", SCRIPT], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "stepped (" in run.stdout, run.stdout
