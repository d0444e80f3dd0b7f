"""The Panda in ciflow beside MuJoCo 4, both loading engine/assets/panda.urdf.

1. Same simulation: MuJoCo is given what URDF cannot carry — ciflow's joint armature —
   and ciflow's integrator (semi-implicit Euler, 1 ms), with its joint limits as imported
   and no contacts (the URDF has no collision geometry). Both are driven open loop by the
   same torques (gravity at the start plus 2 Hz sines) for 0.5 s; the script prints how
   far the arm moved and the largest joint difference between the two (goal <= 1e-3 rad).
   ciflow's side is `engine/examples/open_loop.rs`.
2. Speed: env-steps/s of 4096 Panda environments, 10 physics steps of 1 ms per env step.
   MuJoCo: its C `rollout` module, open-loop torques, on 1 and on 2 threads. ciflow: the
   pouring task (computed torque, 10 substeps, the task's own bookkeeping) served by
   `ciflow serve` on this machine and stepped in batches by the Rust client
   (`bridge/examples/batched_steps.rs`). The runs alternate, best of ROUNDS each, and the
   script prints served / MuJoCo-on-2-threads (goal >= 2).

Run: `python bench/panda_vs_mujoco.py` (needs `pip install 'mujoco==4.0.*'`; builds the
two examples). Nothing else should run on the machine meanwhile.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

try:
    import mujoco
    from mujoco import rollout
except ImportError:
    sys.exit("MuJoCo is missing: pip install 'mujoco==4.0.*'")

ROOT = Path(__file__).resolve().parent.parent
TARGET = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
URDF = ROOT / "engine/assets/panda.urdf"
Q0 = np.array([0.3, -0.5, 0.2, -2.0, 0.4, 1.6, -0.3])
DT = 1e-3
AGREEMENT_STEPS = 500
NUM_ENVS = 4096
SUBSTEPS = 10
ROLLOUT_STEPS = 200  # physics steps per MuJoCo rollout call (20 env steps)
SERVED_SECONDS = 5.0
ROUNDS = 3
ENDPOINT = "tcp/127.0.0.1:27613"


def build():
    for package, example in [("ciflow-engine", "open_loop"), ("ciflow-bridge", "batched_steps")]:
        subprocess.run(
            ["cargo", "build", "--release", "--quiet", "-p", package, "--example", example],
            cwd=ROOT, check=True,
        )
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "ciflow"], cwd=ROOT, check=True)


def mujoco_model(armature):
    model = mujoco.MjSpec.from_file(str(URDF)).compile()
    model.opt.timestep = DT
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    model.dof_armature[:] = armature
    return model


def agreement():
    probe = mujoco.MjSpec.from_file(str(URDF)).compile()
    data = mujoco.MjData(probe)
    data.qpos[:] = Q0
    mujoco.mj_forward(probe, data)
    t = np.arange(AGREEMENT_STEPS) * DT
    shape = np.array([1.0, 1.0, 1.0, 1.0, 0.5, 0.5, 0.2])
    tau = data.qfrc_bias[None, :] + 3.0 * np.sin(2 * np.pi * 2.0 * t)[:, None] * shape
    request = {"q0": Q0.tolist(), "qd0": [0.0] * 7, "physics_dt": DT, "tau": tau.tolist()}
    ciflow = json.loads(subprocess.run(
        [TARGET / "release/examples/open_loop"], input=json.dumps(request),
        capture_output=True, text=True, check=True,
    ).stdout)
    model = mujoco_model(ciflow["armature"])
    data = mujoco.MjData(model)
    data.qpos[:] = Q0
    q_mujoco = []
    for row in tau:
        data.qfrc_applied[:] = row
        mujoco.mj_step(model, data)
        q_mujoco.append(data.qpos.copy())
    q_mujoco, q_ciflow = np.array(q_mujoco), np.array(ciflow["q"])
    moved = np.abs(q_ciflow[-1] - Q0).max()
    worst = np.abs(q_mujoco - q_ciflow).max()
    print(f"== same simulation: {AGREEMENT_STEPS} open-loop steps of {DT * 1e3:g} ms "
          f"(armature {np.round(ciflow['armature'], 3).tolist()})")
    print(f"   the arm moved up to {moved:.3f} rad; largest joint difference ciflow vs "
          f"MuJoCo {worst:.1e} rad (goal <= 1e-3)")
    return model, ciflow["armature"]


def mujoco_rate(model, threads):
    data = mujoco.MjData(model)
    data.qpos[:] = Q0
    mujoco.mj_forward(model, data)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, data, state, full)
    initial = np.tile(state, (NUM_ENVS, 1))
    noise = np.random.default_rng(0).normal(0.0, 1.0, (NUM_ENVS, ROLLOUT_STEPS, model.nv))
    control = data.qfrc_bias[None, None, :] + noise
    datas = [mujoco.MjData(model) for _ in range(threads)]
    start = time.perf_counter()
    rollout.rollout(model, datas, initial, control,
                    control_spec=mujoco.mjtState.mjSTATE_QFRC_APPLIED, nstep=ROLLOUT_STEPS)
    elapsed = time.perf_counter() - start
    return NUM_ENVS * ROLLOUT_STEPS / SUBSTEPS / elapsed


def served_rate():
    engine = subprocess.Popen(
        [TARGET / "release/ciflow", "serve", "--listen", ENDPOINT, "--name", "mujoco-bench"],
        stdout=subprocess.PIPE, text=True,
    )
    try:
        ready = engine.stdout.readline()
        if "ready" not in ready:
            sys.exit(f"ciflow serve did not start: {ready}")
        out = subprocess.run(
            [TARGET / "release/examples/batched_steps", ENDPOINT, "pouring", str(NUM_ENVS),
             str(SERVED_SECONDS)],
            capture_output=True, text=True, check=True,
        ).stdout
        return json.loads(out)["env_steps_per_s"]
    finally:
        engine.terminate()
        engine.wait()


def main():
    build()
    model, _ = agreement()
    rates = {"mujoco 1 thread": [], "mujoco 2 threads": [], "ciflow served": []}
    for _ in range(ROUNDS):
        rates["mujoco 1 thread"].append(mujoco_rate(model, 1))
        rates["mujoco 2 threads"].append(mujoco_rate(model, 2))
        rates["ciflow served"].append(served_rate())
    best = {name: max(values) for name, values in rates.items()}
    print(f"== {NUM_ENVS} environments, {SUBSTEPS} x {DT * 1e3:g} ms physics steps per env "
          f"step, best of {ROUNDS} alternating rounds, {os.cpu_count()} CPUs")
    for name, rate in best.items():
        print(f"   {name:<18} {rate:>10.0f} env-steps/s")
    ratio = best["ciflow served"] / best["mujoco 2 threads"]
    print(f"   ciflow served (pouring, Zenoh, Rust client) / MuJoCo rollout on 2 threads: "
          f"{ratio:.2f} (goal >= 2)")


if __name__ == "__main__":
    main()
