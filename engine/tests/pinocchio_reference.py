"""Reference dynamics of a URDF robot with Pinocchio, for engine/tests/pinocchio.rs.

Usage: pinocchio_reference.py ROBOT.urdf REQUEST.json OUT.json
REQUEST.json: {"armature": [...], "lock": {"joint": position, ...}, "tool": "link",
               "states": [{"q": [...], "qd": [...], "qdd": [...], "tau": [...]}, ...]}
OUT.json:     {"pinocchio": version, "nq": ..., "joints": [names in chain order],
               "results": [{"tau": rnea, "m": crba (symmetrised, row-major),
               "g": computeGeneralizedGravity, "qdd": aba(q, qd, tau),
               "tool_translation": [...], "tool_rotation": row-major 3x3,
               "tool_jacobian": 6 x n row-major, LOCAL_WORLD_ALIGNED}, ...]}
Locked joints are removed with pin.buildReducedModel at their positions (all others at 0).
Gravity is Pinocchio's default, 9.81 m/s^2 along -z.
"""

import json
import sys

import numpy as np
import pinocchio as pin


def reduced_model(urdf, lock):
    model = pin.buildModelFromUrdf(urdf)
    if not lock:
        return model
    missing = [name for name in lock if not model.existJointName(name)]
    if missing:
        raise SystemExit(f"no joint named {missing} in {urdf}")
    held = pin.neutral(model)
    for name, position in lock.items():
        held[model.joints[model.getJointId(name)].idx_q] = position
    ids = [model.getJointId(name) for name in lock]
    return pin.buildReducedModel(model, ids, held)


def main(urdf, request_path, out_path):
    with open(request_path) as f:
        request = json.load(f)
    model = reduced_model(urdf, request.get("lock", {}))
    if model.nq != model.nv:
        raise SystemExit(f"nq = {model.nq} != nv = {model.nv}: continuous joints are not compared")
    # The reflected rotor inertias (Pinocchio adds them to rnea, crba and aba, as the engine).
    model.armature = np.array(request["armature"], dtype=float)
    data = model.createData()
    tool = model.getFrameId(request["tool"])
    if tool == len(model.frames):
        raise SystemExit(f"no frame named {request['tool']}")
    results = []
    for state in request["states"]:
        q, qd, qdd, tau = (np.array(state[k], dtype=float) for k in ("q", "qd", "qdd", "tau"))
        result = {"tau": pin.rnea(model, data, q, qd, qdd).tolist()}
        m = pin.crba(model, data, q)
        result["m"] = (np.triu(m) + np.triu(m, 1).T).flatten().tolist()
        result["g"] = pin.computeGeneralizedGravity(model, data, q).tolist()
        result["qdd"] = pin.aba(model, data, q, qd, tau).tolist()
        pin.framesForwardKinematics(model, data, q)
        placement = data.oMf[tool]
        result["tool_translation"] = placement.translation.tolist()
        result["tool_rotation"] = placement.rotation.flatten().tolist()
        jacobian = pin.computeFrameJacobian(model, data, q, tool, pin.LOCAL_WORLD_ALIGNED)
        result["tool_jacobian"] = jacobian.flatten().tolist()
        results.append(result)
    joints = [name for name in model.names[1:]]
    with open(out_path, "w") as f:
        json.dump(
            {"pinocchio": pin.__version__, "nq": model.nq, "joints": joints, "results": results}, f
        )


if __name__ == "__main__":
    main(*sys.argv[1:4])
