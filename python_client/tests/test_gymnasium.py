"""Every task through ``gymnasium.make`` / ``gymnasium.make_vec`` against an engine in
another process."""

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import ciflow

# pytest runs with --import-mode=importlib: conftest is not on sys.path by itself.
sys.path.insert(0, str(Path(__file__).resolve().parent))
from conftest import free_port  # noqa: E402


@pytest.fixture(params=ciflow.TASK_IDS)
def task_id(request):
    return request.param


def test_import_registers_every_task():
    assert len(ciflow.TASK_IDS) == 5, ciflow.TASK_IDS
    for task_id in ciflow.TASK_IDS:
        spec = gym.spec(task_id)
        assert spec.entry_point == "ciflow.env:CiflowEnv"
        assert spec.vector_entry_point == "ciflow.vector:CiflowVectorEnv"


def test_discover_lists_the_engine_and_every_task(engine):
    endpoint, name = engine
    engines = ciflow.discover(engine=endpoint)
    found = {e["name"]: e for e in engines}
    assert name in found
    served = {t["spec"]["id"] for t in found[name]["tasks"]}
    assert set(ciflow.TASK_IDS) <= served


def test_the_default_endpoint_is_the_one_set_when_asked(engine, monkeypatch):
    """A client of the default endpoint is kept per endpoint: pointing
    ``CIFLOW_DEFAULT_ENDPOINT`` elsewhere reaches the new place, not the old session."""
    endpoint, name = engine
    monkeypatch.setenv("CIFLOW_DEFAULT_ENDPOINT", endpoint)
    assert name in {e["name"] for e in ciflow.discover()}
    monkeypatch.setenv("CIFLOW_DEFAULT_ENDPOINT", f"tcp/127.0.0.1:{free_port()}")
    assert name not in {e["name"] for e in ciflow.discover()}


def test_check_env_passes(task_id, engine):
    env = gym.make(task_id, engine=engine[0], render_mode="rgb_array")
    try:
        check_env(env.unwrapped)
    finally:
        env.close()


def test_episode_with_expert_context_and_frames(task_id, engine):
    env = gym.make(task_id, engine=engine[0], render_mode="rgb_array", width=64, height=48)
    try:
        inner = env.unwrapped
        k = inner.context_space.shape[0]
        # Contexts the task itself drew (a box sample may be invalid, e.g. overlapping
        # obstacles).
        other_context = env.reset(seed=6)[0][-k:]
        context = env.reset(seed=7)[0][-k:]
        first, _ = env.reset(seed=5, options={"context": context})
        again, _ = env.reset(seed=5, options={"context": context})
        np.testing.assert_array_equal(first, again)
        assert first.shape == env.observation_space.shape
        np.testing.assert_allclose(first[-k:], context, rtol=1e-6, atol=1e-6)

        for _ in range(3):
            action = inner.expert_action()
            assert env.action_space.contains(action.astype(env.action_space.dtype))
            observation, reward, terminated, truncated, info = env.step(action)
            assert np.isfinite(observation).all() and np.isfinite(reward)
        assert info["time"] == pytest.approx(3 * inner.task_spec["control_dt"])

        assert inner.set_context(other_context) == pytest.approx(info["time"])
        observation, *_ = env.step(inner.expert_action())
        np.testing.assert_allclose(observation[-k:], other_context, rtol=1e-6, atol=1e-6)

        dof = env.action_space.shape[0]
        accepted = inner.perturb_joint_torque(np.ones(dof), duration=0.05)
        assert accepted == pytest.approx(4 * inner.task_spec["control_dt"])

        frame = env.render()
        assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
    finally:
        env.close()


def test_bad_input_raises_typed_errors_and_the_env_stays_usable(engine):
    env = gym.make("ciflow/LimitCycle-v0", engine=engine[0]).unwrapped
    try:
        env.reset(seed=0)
        with pytest.raises(ciflow.CiflowError) as nan:
            env.step(np.full(env.action_space.shape, np.nan))
        assert nan.value.code == "not_finite"
        # Refused by shape, as Box.contains would: never flattened into another action.
        dof = env.action_space.shape[0]
        for action in (np.zeros(dof + 1), np.zeros((1, dof)), np.zeros((dof, 1)), 0.0):
            with pytest.raises(ValueError, match=rf"takes \({dof},\)"):
                env.step(action)
        with pytest.raises(ciflow.CiflowError) as context:
            env.reset(options={"context": env.context_space.high + 1.0})
        assert context.value.code == "out_of_bounds"
        for seed in (2**64, -1, 1.5):
            with pytest.raises(ValueError, match="a seed is a whole number"):
                env.reset(seed=seed)
        env.reset(seed=0)
        observation, *_ = env.step(env.expert_action())
        assert np.isfinite(observation).all()
    finally:
        env.close()


def test_a_context_can_be_checked_before_it_is_used(engine):
    env = gym.make("ciflow/Obstacle-v0", engine=engine[0], obstacles=1).unwrapped
    try:
        observation, _ = env.reset(seed=0)
        assert env.check_context(observation[-4:]) is None
        low, high = env.context_space.low, env.context_space.high
        # Obstacle and target at their regions' nearest edges: inside the box, refused.
        near = np.array([high[0], 0.0, low[2], 0.0])
        assert env.context_space.contains(near.astype(env.context_space.dtype))
        reason = env.check_context(near)
        assert reason is not None and "safety disc" in reason
        with pytest.raises(ciflow.CiflowError) as refused:
            env.reset(options={"context": near})
        assert refused.value.code == "out_of_bounds"
    finally:
        env.close()


def test_options_and_perturbations_cross_as_dicts_with_clear_errors(engine):
    env = gym.make("ciflow/LimitCycle-v0", engine=engine[0]).unwrapped
    try:
        # A task-specific option folds into `extra`; an unknown one is the task's to refuse.
        with pytest.raises(ciflow.CiflowError) as unknown:
            env.reset(seed=0, options={"no_such_option": 1.0})
        assert unknown.value.code == "invalid_option"
        with pytest.raises(ValueError, match="`context` has the wrong type"):
            env._session.reset(0, {"context": "not numbers"})
        env.reset(seed=0)
        with pytest.raises(ValueError, match="`duration` is required"):
            env._session.control().perturb({"kind": "link_wrench", "link": 0, "force": [1.0, 0.0, 0.0]})
        with pytest.raises(ValueError, match="neither `joint_torque` nor `link_wrench`"):
            env._session.control().perturb({"kind": "shove", "duration": 0.1})
        accepted = env._session.control().perturb(
            {"kind": "link_wrench", "link": 0, "force": [1.0, 0.0, 0.0], "duration": 0.1}
        )
        assert accepted >= 0.0
        # A push that could never act is refused, not silently dropped.
        for _ in range(5):
            env.step(env.expert_action())
        for start, duration in ((0.0, 0.02), (env.sim_time, 0.0)):
            with pytest.raises(ciflow.CiflowError) as never:
                env.perturb_joint_torque(np.ones(2), duration=duration, start=start)
            assert never.value.code == "invalid_perturbation"
            assert "invalid perturbation: invalid perturbation" not in str(never.value)
        assert env.perturb_joint_torque(np.ones(2), duration=0.1, start=0.0) == env.sim_time
        # A token that is not hexadecimal is named, from the API and the command line.
        with pytest.raises(ValueError, match="not hexadecimal"):
            ciflow.attach(env.session_id, "zz", engine=engine[0])
        done = subprocess.run(
            [sys.executable, "-m", "ciflow.perturb", "--session", env.session_id, "--token",
             "zz", "--engine", engine[0]], capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and "not hexadecimal" in done.stderr, done.stderr
        # An engine without policies says how to give it one.
        with pytest.raises(ciflow.CiflowError, match="serves none .*--policy nobody="):
            env.run_policy("nobody")
    finally:
        env.close()


def test_make_vec_steps_all_environments_in_one_request(task_id, engine):
    n = 8
    envs = gym.make_vec(task_id, num_envs=n, engine=engine[0])
    try:
        assert isinstance(envs.unwrapped, ciflow.CiflowVectorEnv)
        assert envs.unwrapped._shares == [n], "one session, one request per step"
        observations, _ = envs.reset(seed=100)
        assert observations.shape == (n,) + envs.single_observation_space.shape
        single = gym.make(task_id, engine=engine[0])
        first, _ = single.reset(seed=103)
        single.close()
        np.testing.assert_array_equal(observations[3], first)
        envs.action_space.seed(0)
        for _ in range(5):
            observations, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())
            assert observations.shape[0] == rewards.shape[0] == terminated.shape[0] == n
            assert envs.observation_space.contains(observations) or np.isfinite(observations).all()
    finally:
        envs.close()



def test_make_vec_returns_arrays_the_caller_owns(engine):
    """Every array of a batched reset and step is writable and shares no memory with any
    other array returned, by the same call or another: a caller may keep them or change
    them in place."""
    envs = gym.make_vec("ciflow/Obstacle-v0", num_envs=3, engine=engine[0], obstacles=1)
    try:
        push = np.full((3, 2), 0.5)
        observations, info = envs.reset(seed=0)
        returned = [observations, *info.values()]
        for _ in range(3):
            observations, rewards, terminated, truncated, info = envs.step(push)
            assert info, "the obstacle task reports info"
            returned += [observations, rewards, terminated, truncated, *info.values()]
        assert observations.dtype == envs.single_observation_space.dtype
        assert rewards.dtype == np.float64
        assert terminated.dtype == truncated.dtype == np.bool_
        for i, array in enumerate(returned):
            assert array.flags.writeable, f"array {i} is read-only"
            for j, other in enumerate(returned[i + 1:], start=i + 1):
                assert not np.shares_memory(array, other), f"arrays {i} and {j} share memory"
        kept = observations.copy()
        observations[:] = np.nan
        following, *_ = envs.step(push)
        assert np.isfinite(following).all(), "a changed array reached the next step"
        assert not np.array_equal(following, kept), "the environments moved"
    finally:
        envs.close()


# Run in a fresh interpreter, as a user's script is: glibc's allocator adapts its
# thresholds to what a process freed before, so a long-lived test process would not show
# what a new one does.
FAULTS_PER_STEP = """
import json, mmap, resource, sys
import gymnasium as gym
import numpy as np
import ciflow

def minor_page_faults():
    # First touches of memory the kernel had not given this process before.
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt

# Negative control: the count sees fresh pages touched in this process.
pages, page = 64, mmap.PAGESIZE
before = minor_page_faults()
for _ in range(10):
    with mmap.mmap(-1, pages * page) as fresh:
        for offset in range(0, pages * page, page):
            fresh[offset] = 1
control = (minor_page_faults() - before) / (10 * pages)

num_envs, steps = 4096, 50
envs = gym.make_vec("ciflow/LimitCycle-v0", num_envs=num_envs, engine=sys.argv[1])
actions = np.zeros((num_envs,) + envs.single_action_space.shape)
envs.reset(seed=0)
for _ in range(20):  # the allocator's pools reach their working size
    envs.step(actions)
before = minor_page_faults()
for _ in range(steps):
    envs.step(actions)
per_step = (minor_page_faults() - before) / steps
envs.close()
print(json.dumps({"control": control, "per_step": per_step}))
"""


def test_batched_steps_reuse_their_memory_instead_of_faulting_it_in_again(engine):
    """A step of 4 096 environments allocates some hundred KiB in the client. They must be
    reused from one step to the next: with glibc's allocator the extension gave them back
    to the kernel and faulted them in again at every step (about 90 faults per step, half
    the client's CPU)."""
    run = subprocess.run([sys.executable, "-c", FAULTS_PER_STEP, engine[0]],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    counts = json.loads(run.stdout.strip().splitlines()[-1])
    assert counts["control"] >= 1.0, f"the count missed fresh pages: {counts}"
    assert counts["per_step"] < 5, f"{counts['per_step']:.1f} page faults per step"

OBSTACLE_CONTEXTS = np.array([[0.0, 0.3, 0.8, 0.1], [0.1, -0.3, 0.7, -0.2], [-0.2, 0.0, 0.9, 0.4]])


def test_make_vec_takes_one_row_of_reset_options_per_environment(engine):
    envs = gym.make_vec("ciflow/Obstacle-v0", num_envs=3, engine=engine[0], obstacles=1)
    try:
        starts = np.array([[-0.9, 0.1], [-0.8, -0.2], [-0.7, 0.5]])
        observations, _ = envs.reset(
            seed=0, options={"context": OBSTACLE_CONTEXTS, "initial_position": starts})
        np.testing.assert_array_equal(observations[:, 4:], OBSTACLE_CONTEXTS)
        np.testing.assert_array_equal(observations[:, :2], starts)
        # Through the episode's end and the autoreset after it, each keeps its own row.
        ended = np.zeros(3, dtype=bool)
        while not ended.all():
            observations, _, terminated, truncated, _ = envs.step(np.zeros((3, 2)))
            ended |= terminated | truncated
        observations, *_ = envs.step(np.zeros((3, 2)))
        np.testing.assert_array_equal(observations[:, 4:], OBSTACLE_CONTEXTS)
        np.testing.assert_array_equal(observations[:, :2], starts)
        # One value is every environment's.
        observations, _ = envs.reset(seed=0, options={"context": OBSTACLE_CONTEXTS[1]})
        np.testing.assert_array_equal(observations[:, 4:], np.tile(OBSTACLE_CONTEXTS[1], (3, 1)))
        # Two rows for three environments: neither one value nor a row each.
        with pytest.raises(ValueError, match="context has 8 numbers; a batch of 3 environments "
                           r"takes 4 \(one value for every environment\) or 12"):
            envs.reset(options={"context": OBSTACLE_CONTEXTS[:2]})
    finally:
        envs.close()


def test_make_vec_takes_a_seed_per_environment_as_sync_vector_env_does(engine):
    envs = gym.make_vec("ciflow/Obstacle-v0", num_envs=3, engine=engine[0], obstacles=1)
    try:
        listed, _ = envs.reset(seed=[7, 8, 9])
        counted, _ = envs.reset(seed=7)
        np.testing.assert_array_equal(listed, counted)
        reordered, _ = envs.reset(seed=np.array([9, 8, 7]))
        np.testing.assert_array_equal(reordered, counted[::-1])
        # `None`: that environment's RNG continues, so it does not start as seeded again.
        continued, _ = envs.reset(seed=[7, None, 9])
        np.testing.assert_array_equal(continued[[0, 2]], counted[[0, 2]])
        assert not np.array_equal(continued[1], counted[1])
    finally:
        envs.close()


def test_make_vec_refuses_bad_sizes_seeds_and_action_shapes(engine):
    for num_envs in (0, -1, 2.5):
        with pytest.raises(ValueError, match="num_envs"):
            gym.make_vec("ciflow/Obstacle-v0", num_envs=num_envs, engine=engine[0])
    envs = gym.make_vec("ciflow/Obstacle-v0", num_envs=3, engine=engine[0], obstacles=1)
    try:
        for seeds, message in (([1, 2], "2 seeds for 3"), ([1, -2, 3], "whole number"),
                               ([1, 2.5, 3], "whole number"), (2**70, "whole number")):
            with pytest.raises(ValueError, match=message):
                envs.reset(seed=seeds)
        envs.reset(seed=0)
        for actions in (np.zeros((2, 2)), np.zeros(6), np.zeros((1, 6))):
            with pytest.raises(ValueError, match=r"\(3, 2\)"):
                envs.step(actions)
        envs.step([[0.0, 0.0]] * 3)
    finally:
        envs.close()


def test_unreachable_engine_says_how_to_start_one():
    with pytest.raises(ciflow.EngineUnreachable) as error:
        gym.make("ciflow/LimitCycle-v0", engine="tcp/127.0.0.1:9")
    assert "ciflow serve" in str(error.value)


ASYNC_SCRIPT = """
import sys
import gymnasium as gym
import numpy as np
import ciflow  # noqa: F401

if __name__ == "__main__":
    envs = gym.make_vec("ciflow/LimitCycle-v0", num_envs=2, engine=sys.argv[1],
                        vectorization_mode="async", vector_kwargs={"context": sys.argv[2]})
    envs.reset(seed=0)
    observations, *_ = envs.step(np.zeros((2, 2)))
    print("stepped", observations.shape)
    envs.close()
"""


def test_gymnasium_s_async_vector_env_works_with_spawn_and_says_why_not_with_fork(
        engine, tmp_path):
    """Zenoh's threads do not survive fork: a worker forked after the parent opened a
    session (Gymnasium opens one for the spaces) used to hang on its first request. It
    now fails at once, naming the fix; spawned workers work."""
    script = tmp_path / "async_envs.py"
    script.write_text(ASYNC_SCRIPT)
    spawned = subprocess.run([sys.executable, str(script), engine[0], "spawn"],
                             capture_output=True, text=True, timeout=120)
    assert spawned.returncode == 0 and "stepped (2, 5)" in spawned.stdout, spawned.stderr
    forked = subprocess.run([sys.executable, str(script), engine[0], "fork"],
                            capture_output=True, text=True, timeout=120)
    assert forked.returncode != 0
    assert "forked after its parent opened one" in forked.stderr, forked.stderr
