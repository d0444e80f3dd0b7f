"""Reference dynamics of a URDF robot with Pinocchio, for engine/tests/pinocchio.rs.

Usage: pinocchio_reference.py ROBOT.urdf STATES.json OUT.json
STATES.json: {"armature": [...], "states": [{"q": [...], "qd": [...], "qdd": [...]}, ...]}
OUT.json:    {"pinocchio": version, "results": [{"tau": rnea, "m": crba (symmetrised,
             row-major), "g": computeGeneralizedGravity}, ...]}
Gravity is Pinocchio's default, 9.81 m/s^2 along -z.
"""

import json
import sys

import numpy as np
import pinocchio as pin


def main(urdf, states_path, out_path):
    with open(states_path) as f:
        request = json.load(f)
    model = pin.buildModelFromUrdf(urdf)
    # The reflected rotor inertias (Pinocchio adds them to rnea and crba, as the engine).
    model.armature = np.array(request["armature"], dtype=float)
    data = model.createData()
    states = request["states"]
    results = []
    for state in states:
        q, qd, qdd = (np.array(state[k], dtype=float) for k in ("q", "qd", "qdd"))
        tau = pin.rnea(model, data, q, qd, qdd).copy()
        m = pin.crba(model, data, q).copy()
        m = np.triu(m) + np.triu(m, 1).T
        g = pin.computeGeneralizedGravity(model, data, q).copy()
        results.append({"tau": tau.tolist(), "m": m.flatten().tolist(), "g": g.tolist()})
    with open(out_path, "w") as f:
        json.dump({"pinocchio": pin.__version__, "nq": model.nq, "results": results}, f)


if __name__ == "__main__":
    main(*sys.argv[1:4])
