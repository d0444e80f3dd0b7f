"""Sanity checks of the test URDFs: Pinocchio and/or MuJoCo, whichever this Python has.

Pinocchio: the file loads, nq is as expected, M(q) from CRBA equals the one built column by
column from RNEA and is positive definite, gravity torques are not trivially zero, and at
q = 0 the tool sits where the manufacturer's dimensions put it. MuJoCo: the file compiles.

Run: .venv/bin/python engine/tests/assets/check_arm_urdfs.py
"""

import importlib.util
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

# file, nq, tool frame, its position at q = 0 in the root link's frame from the spec's
# dimensions (None: not checked), joints to lock for a serial chain.
CASES = [
    # UR5e, in UR's base frame: x = a2 + a3, y = -(d4 + d6), z = d1 - d5; base_link is that
    # frame turned by pi about z, so x and y change sign.
    ("ur5e.urdf", 6, "tool0", (0.425 + 0.3922, 0.1333 + 0.0996, 0.1625 - 0.0997), {}),
    # iiwa 14 standing straight up: 0.36 + 0.42 + 0.40 + 0.126 m above the mounting face.
    ("iiwa14.urdf", 7, "iiwa_link_ee", (0.0, 0.0, 0.36 + 0.42 + 0.40 + 0.126), {}),
    # Panda at q = 0 (from its DH table): x = 0.0825 - 0.0825 + 0.088, z = 0.333 + 0.316 + 0.384 - 0.107;
    # the finger joint frames sit 0.0584 m further down the hand's z.
    ("panda_gripper.urdf", 9, "panda_leftfinger", (0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107 - 0.0584), {}),
    ("panda_gripper.urdf", 8, "panda_leftfinger", None, {"panda_finger_joint2": 0.02}),
]


def check_pinocchio(pin):
    rng = np.random.default_rng(0)
    for name, nq, tool, expected, lock in CASES:
        model = pin.buildModelFromUrdf(str(HERE / name))
        if lock:
            held = pin.neutral(model)
            for joint, position in lock.items():
                held[model.joints[model.getJointId(joint)].idx_q] = position
            model = pin.buildReducedModel(model, [model.getJointId(j) for j in lock], held)
        data = model.createData()
        assert model.nq == nq, (name, model.nq)
        lo, hi = model.lowerPositionLimit, model.upperPositionLimit
        worst_sym, min_eig, min_g = 0.0, np.inf, np.inf
        for _ in range(20):
            q = rng.uniform(lo, hi)
            m = pin.crba(model, data, q)
            m = np.triu(m) + np.triu(m, 1).T  # Pinocchio fills the upper triangle
            g = pin.computeGeneralizedGravity(model, data, q)
            # M column by column from RNEA: independent of CRBA, and not symmetrised.
            cols = np.column_stack([pin.rnea(model, data, q, np.zeros(nq), e) - g for e in np.eye(nq)])
            worst_sym = max(worst_sym, np.abs(cols - cols.T).max() / np.abs(cols).max(),
                            np.abs(cols - m).max() / np.abs(m).max())
            min_eig = min(min_eig, np.linalg.eigvalsh(m).min())
            min_g = min(min_g, np.linalg.norm(g))
        pin.framesForwardKinematics(model, data, pin.neutral(model))
        at_zero = data.oMf[model.getFrameId(tool)].translation
        tag = f"{name} (locked {lock})" if lock else name
        print(f"{tag}: nq={model.nq} joints={list(model.names)[1:]}")
        print(f"  M: CRBA vs RNEA columns / asymmetry rel. {worst_sym:.1e}, min eigenvalue {min_eig:.3e}, "
              f"min |g(q)| {min_g:.2f} N m (20 random q)")
        line = f"  {tool} at q=0: {np.round(at_zero, 6).tolist()}"
        if expected is not None:
            error = np.abs(at_zero - np.array(expected)).max()
            line += f"  spec: {np.round(expected, 6).tolist()}  |error| {error:.1e}"
            assert error < 1e-12, line
        print(line)
        assert worst_sym < 1e-12 and min_eig > 0 and min_g > 1.0, tag


def check_mujoco(mujoco):
    for name in sorted({case[0] for case in CASES}):
        try:
            model = mujoco.MjModel.from_xml_path(str(HERE / name))
            print(f"MuJoCo {mujoco.__version__} {name}: nq={model.nq} nbody={model.nbody}")
        except Exception as error:  # report, do not fight it
            print(f"MuJoCo {mujoco.__version__} {name}: refused: {error}")


if __name__ == "__main__":
    for module, check in (("pinocchio", check_pinocchio), ("mujoco", check_mujoco)):
        if importlib.util.find_spec(module) is None:
            print(f"({module} not installed here: skipped)")
        else:
            check(importlib.import_module(module))
