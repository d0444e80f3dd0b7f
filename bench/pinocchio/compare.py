"""Side-by-side timing of ciflow's dynamics and Pinocchio's (compiled C++), driven by
bench/dynamics_vs_pinocchio.sh.

Usage: compare.py ROBOT.urdf CIFLOW_TIMING PINOCCHIO_TIMING WORKDIR

1. Parses ROBOT.urdf with Pinocchio's own parser and writes the tree for the C++ program
   (`model.txt`, see `write_model`); ciflow parses the same URDF itself.
2. Draws random states within the joint limits (`states.txt`), read by both programs.
3. Checks that both compute the same numbers on every state (else exits 1: a ratio of
   different work means nothing).
4. Times both in alternating runs (the order flips every round, so load that drifts over
   the run hits both alike) and prints ns per call and the ratio ciflow / Pinocchio, the
   median over rounds of the per-round ratios, with its range.

Environment: ROUNDS (default 5), BATCH_MS (default 2), STATES (default 64), SEED (default 7).
"""

import json
import os
import statistics
import subprocess
import sys

import numpy as np
import pinocchio as pin

TOLERANCE = 1e-9

# (label, ciflow key, Pinocchio key): the table's rows.
ROWS = [
    ("RNEA  tau(q, qd, qdd)", "rnea", "rnea"),
    ("CRBA  M(q)", "crba", "crba"),
    ("gravity  g(q)", "gravity", "gravity"),
    ("nonlinear effects  C qd + g", "nonlinear_effects", "nonlinear_effects"),
    ("Coriolis matrix  C(q, qd)", "coriolis", "coriolis"),
    ("forward dynamics vs ABA", "forward_dynamics", "forward_dynamics_aba"),
    ("forward dynamics vs CRBA+Cholesky", "forward_dynamics", "forward_dynamics_cholesky"),
]


def write_model(model, path):
    """One line per joint: `parent type R(9, row-major) p(3) mass com(3) I_com(9)`, the
    joint placement in its parent and the body inertia (fixed joints already lumped by
    the URDF parser); `type` is RX, RY or RZ, or RU and the unit axis (3)."""
    lines = [str(model.njoints - 1)]
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = joint.shortname()
        if name in ("JointModelRX", "JointModelRY", "JointModelRZ"):
            kind = [name[-2:]]
        elif name == "JointModelRevoluteUnaligned":
            kind = ["RU", *(repr(float(a)) for a in joint.axis)]
        else:
            sys.exit(f"compare.py: joint type {name} is not supported")
        placement, inertia = model.jointPlacements[j], model.inertias[j]
        numbers = [
            *placement.rotation.flatten(),
            *placement.translation,
            inertia.mass,
            *inertia.lever,
            *inertia.inertia.flatten(),
        ]
        lines.append(" ".join([str(model.parents[j]), *kind, *(repr(float(x)) for x in numbers)]))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def write_states(model, count, seed, path):
    """`nv count`, then per state q (within the position limits), qd (within the velocity
    limits), qdd (|qdd| < 10 rad/s²) and tau (within half the effort limits)."""
    rng = np.random.default_rng(seed)
    nv = model.nv
    lines = [f"{nv} {count}"]
    for _ in range(count):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        qd = rng.uniform(-model.velocityLimit, model.velocityLimit)
        qdd = rng.uniform(-10.0, 10.0, nv)
        tau = rng.uniform(-0.5 * model.effortLimit, 0.5 * model.effortLimit)
        lines.append(" ".join(repr(float(x)) for x in np.concatenate([q, qd, qdd, tau])))
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def run(command):
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"compare.py: {' '.join(command)} failed:\n{result.stderr}")
    return json.loads(result.stdout)


def check_agreement(ciflow, pinocchio):
    """Largest |ciflow − Pinocchio| / max(1, |Pinocchio|) per row; exits if any is too big."""
    failed = False
    for label, ours, theirs in ROWS:
        a, b = np.array(ciflow[ours]), np.array(pinocchio[theirs])
        if a.shape != b.shape:
            sys.exit(f"compare.py: {label}: shapes {a.shape} vs {b.shape}")
        error = float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b))))
        ok = error <= TOLERANCE
        failed |= not ok
        print(f"  {'ok ' if ok else 'BAD'} {label:<36} max rel. difference {error:.1e}")
    if failed:
        sys.exit(f"compare.py: the two libraries disagree (tolerance {TOLERANCE:g}): not timing")


def main(urdf, ciflow_bin, pinocchio_bin, workdir):
    rounds = int(os.environ.get("ROUNDS", 5))
    batch_ms = os.environ.get("BATCH_MS", "2")
    model = pin.buildModelFromUrdf(urdf)
    model_path = os.path.join(workdir, "model.txt")
    states_path = os.path.join(workdir, "states.txt")
    write_model(model, model_path)
    count = int(os.environ.get("STATES", 64))
    write_states(model, count, int(os.environ.get("SEED", 7)), states_path)
    ciflow_cmd = [ciflow_bin, urdf, states_path]
    pinocchio_cmd = [pinocchio_bin, model_path, states_path]

    print(f"== same numbers? {count} random states, nv = {model.nv}")
    check_agreement(run(ciflow_cmd + ["values"]), run(pinocchio_cmd + ["values"]))

    print(f"== timing: {rounds} rounds, order flipped each round, best of 25 batches of ~{batch_ms} ms")
    ours, theirs = [], []
    for r in range(rounds):
        order = [(ours, ciflow_cmd), (theirs, pinocchio_cmd)]
        for times, command in order if r % 2 == 0 else reversed(order):
            times.append(run(command + ["time", batch_ms]))

    print()
    print(f"| {'algorithm (Panda, ns/call)':<36} | {'ciflow':>8} | {'Pinocchio':>9} | {'ciflow/Pinocchio':>22} |")
    print(f"|{'-' * 38}|{'-' * 9}:|{'-' * 10}:|{'-' * 23}:|")
    for label, key_ours, key_theirs in ROWS:
        ns_ours = [t[key_ours] for t in ours]
        ns_theirs = [t[key_theirs] for t in theirs]
        ratios = [a / b for a, b in zip(ns_ours, ns_theirs)]
        spread = f"({min(ratios):.2f}–{max(ratios):.2f})"
        print(
            f"| {label:<36} | {statistics.median(ns_ours):>8.0f} | {statistics.median(ns_theirs):>9.0f} "
            f"| {statistics.median(ratios):>6.2f} {spread:>15} |"
        )


if __name__ == "__main__":
    main(*sys.argv[1:5])
