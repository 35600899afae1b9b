"""Independent reference: loads a URDF in MuJoCo and prints its joint-space mass matrix and bias forces (Coriolis,
centrifugal and gravity) for given states, as JSON. stdin: {"urdf": path, "states": [{"q": [...], "qd": [...]}]}"""
import json
import sys

import mujoco
import numpy as np


def main() -> None:
    request = json.load(sys.stdin)
    model = mujoco.MjModel.from_xml_path(request["urdf"])
    data = mujoco.MjData(model)
    out = []
    for s in request["states"]:
        data.qpos[:] = s["q"]
        data.qvel[:] = s["qd"]
        mujoco.mj_forward(model, data)
        m = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, m)
        out.append({"mass_matrix": m.tolist(), "bias": data.qfrc_bias.tolist(), "nq": model.nq})
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
