"""Bring your own robot, end to end on an arm that is not the Panda: demonstrations of
``ciflow/Reach-v0`` on a UR5e (its URDF from the test assets), a policy trained on them,
served by ``ciflow serve``, and stepped from Python through ``gymnasium.make`` with the
same URDF; over 50 new goals the policy ends within 1 cm of the goal in at least 90 %.
The unconstrained MLP trained beside it acts on the same arm."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import ciflow

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import BINARY, ciflow_cli, free_port  # noqa: E402

UR5E = Path(__file__).resolve().parents[2] / "engine" / "tests" / "assets" / "ur5e.urdf"
ARGUMENTS = {"urdf": str(UR5E), "tool": "tool0", "home": "0,-1.57,1.57,-1.57,-1.57,0"}
DEMONSTRATIONS = 500
GOALS = 50
SUCCESS_RADIUS = 0.01


@pytest.fixture(scope="module")
def reach_engine(tmp_path_factory):
    """(endpoint, name, checkpoint) of `ciflow serve` with a UR5e reach policy `reach`, and
    the policy's checkpoint (the MLP trained beside it in `baseline/`)."""
    if not BINARY.exists():
        pytest.skip(f"{BINARY} not built (cargo build --release)")
    scratch = tmp_path_factory.mktemp("reach")
    kwargs = [arg for key, value in ARGUMENTS.items() for arg in ("--kwarg", f"{key}={value}")]
    ciflow_cli("demos", "--task", "reach", *kwargs, "--episodes", DEMONSTRATIONS,
               "--out", scratch / "demos")
    ciflow_cli("train", "--task", "reach", "--demos", scratch / "demos", "--out", scratch / "ur5e",
               "--baseline")
    endpoint, name = f"tcp/127.0.0.1:{free_port()}", "pytest-reach"
    # The checkpoint recorded the URDF: the engine builds the UR5e task without --policy-kwarg.
    process = subprocess.Popen(
        [str(BINARY), "serve", "--listen", endpoint, "--name", name,
         "--policy", f"reach={scratch / 'ur5e'}"],
        stdout=subprocess.PIPE, text=True,
    )
    assert "ready" in process.stdout.readline()
    yield endpoint, name, scratch / "ur5e"
    process.terminate()
    process.wait(timeout=10)


def test_a_policy_learned_on_a_ur5e_reaches_new_goals_from_python(reach_engine):
    endpoint, *_ = reach_engine
    policy = ciflow.Policy("reach", engine=endpoint)
    assert (policy.task, policy.observation_dim, policy.action_dim) == ("ciflow/Reach-v0", 15, 6)
    env = gym.make("ciflow/Reach-v0", engine=endpoint, **ARGUMENTS)
    assert env.action_space.shape == (6,)
    final = []
    for goal in range(GOALS):
        # Seeds far from the demonstrations' 0..499: goals the policy has not seen.
        observation, _ = env.reset(seed=100_000 + goal)
        truncated = False
        while not truncated:
            observation, _, terminated, truncated, info = env.step(policy.act(observation))
            assert not terminated
        final.append(info["distance_to_target"])
    env.close()
    final = np.array(final)
    reached = float(np.mean(final < SUCCESS_RADIUS))
    print(f"UR5e reach: {reached:.0%} of {GOALS} new goals within 1 cm, "
          f"median final distance {1000 * np.median(final):.1f} mm")
    assert reached >= 0.9, final


def test_the_panda_default_is_another_task_than_the_ur5e(reach_engine):
    # The environment's identity holds the arm: the same id without a URDF is the Panda's.
    endpoint, *_ = reach_engine
    panda = gym.make("ciflow/Reach-v0", engine=endpoint)
    ur5e = gym.make("ciflow/Reach-v0", engine=endpoint, **ARGUMENTS)
    assert panda.action_space.shape == (7,) and ur5e.action_space.shape == (6,)
    with pytest.raises(ValueError, match="cannot read"):
        gym.make("ciflow/Reach-v0", engine=endpoint, urdf="/nonexistent/arm.urdf")
    panda.close()
    ur5e.close()


def test_the_mlp_trained_beside_it_acts_on_the_same_arm(reach_engine):
    # The baseline's checkpoint records the URDF too: evaluated, it builds the UR5e's task.
    *_, checkpoint = reach_engine
    out = checkpoint.parent / "baseline-eval.json"
    ciflow_cli("evaluate", "--checkpoint", checkpoint / "baseline", "--episodes", 2, "--seed",
               100_000, "--out", out)
    report = json.loads(out.read_text())
    assert report["model"] == "baseline"
    assert [len(result["start"]) for result in report["results"]] == [6, 6]
