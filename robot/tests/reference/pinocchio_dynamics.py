"""Independent reference: evaluates Pinocchio's algorithms on a URDF for given states.

Reads JSON from stdin: {"urdf": path, "states": [{"q": [...], "qd": [...], "qdd": [...], "tau": [...]}, ...],
"lock": {joint: position}} ("lock" optional: those joints are held at the position, Pinocchio's reduced model).
Writes JSON to stdout: one entry per state with Pinocchio's rnea, aba, crba, nonlinear effects, the joint torque
regressor and the LOCAL_WORLD_ALIGNED Jacobian of the last joint frame's origin.
With --ur5 or --panda, prints the path of that URDF shipped by example-robot-data instead.
"""
import json
import pathlib
import sys
import sysconfig

import numpy as np
import pinocchio as pin


ROBOTS = {
    "--ur5": "ur_description/urdf/ur5_robot.urdf",
    "--panda": "panda_description/urdf/panda.urdf",
}


def robot_path(flag: str) -> str:
    prefix = pathlib.Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix"
    return str(prefix / "share/example-robot-data/robots" / ROBOTS[flag])


def main() -> None:
    for flag in ROBOTS:
        if flag in sys.argv:
            print(robot_path(flag))
            return
    request = json.load(sys.stdin)
    model = pin.buildModelFromUrdf(request["urdf"])
    lock = request.get("lock", {})
    if lock:
        q0 = pin.neutral(model)
        ids = []
        for name, value in lock.items():
            jid = model.getJointId(name)
            q0[model.joints[jid].idx_q] = value
            ids.append(jid)
        model = pin.buildReducedModel(model, ids, q0)
    data = model.createData()
    last = model.njoints - 1
    out = []
    for s in request["states"]:
        q, qd, qdd, tau = (np.array(s[k], dtype=float) for k in ("q", "qd", "qdd", "tau"))
        entry = {
            "rnea": pin.rnea(model, data, q, qd, qdd).tolist(),
            "aba": pin.aba(model, data, q, qd, tau).tolist(),
            "nle": pin.nonLinearEffects(model, data, q, qd).tolist(),
        }
        crba = pin.crba(model, data, q)
        entry["crba"] = (np.triu(crba) + np.triu(crba, 1).T).tolist()  # crba fills only the upper triangle
        entry["regressor"] = pin.computeJointTorqueRegressor(model, data, q, qd, qdd).tolist()
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        entry["jacobian"] = pin.getJointJacobian(model, data, last, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).tolist()
        out.append(entry)
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
