"""MuJoCo side of bench/simulation.sh: cost per simulated millisecond and energy drift of the same torque-free swing of
the same URDFs, with MuJoCo's default semi-implicit Euler and with its RK4, each at 1, 0.5 and 0.25 ms. Contacts and
joint limits are disabled (dynforge's engines have neither); stepping is timed in MuJoCo's native rollout (no Python
per step). Usage: mujoco_engine.py SECONDS ID=URDF [ID=URDF ...]"""
import json
import sys
import time

import mujoco
import numpy as np
from mujoco import rollout

Q0 = [0.3, 0.9, -0.7, 1.1, 0.4, -0.8]
QD0 = [0.5, -0.3, 0.8, -1.0, 2.0, 1.5]


def run(robot: int, path: str, seconds: float, integrator: int, name: str, h_ms: float) -> dict:
    model = mujoco.MjModel.from_xml_path(path)
    model.opt.timestep = h_ms * 1e-3
    model.opt.integrator = integrator
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    model.opt.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY
    model.jnt_limited[:] = 0
    data = mujoco.MjData(model)
    data.qpos[:] = Q0
    data.qvel[:] = QD0
    mujoco.mj_forward(model, data)
    steps = int(round(seconds / model.opt.timestep))
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, state, spec)
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        rollout.rollout(model, data, state[None, :], nstep=steps)
        best = min(best, time.perf_counter() - start)
    # Energy drift over the same run, stepped from Python (untimed).
    mujoco.mj_setState(model, data, state, spec)
    mujoco.mj_forward(model, data)
    e0 = data.energy[0] + data.energy[1]
    drift, peak = 0.0, 0.0
    for _ in range(steps):
        mujoco.mj_step(model, data)
        drift = max(drift, abs(data.energy[0] + data.energy[1] - e0))
        peak = max(peak, data.energy[1])
    return {"robot": robot, "engine": name, "h_ms": h_ms, "us_per_ms": best * 1e6 / (seconds * 1e3),
            "energy_drift": drift / peak}


def main() -> None:
    seconds = float(sys.argv[1])
    for arg in sys.argv[2:]:
        robot, path = arg.split("=", 1)
        for integrator, name in [(mujoco.mjtIntegrator.mjINT_EULER, "mujoco_euler"), (mujoco.mjtIntegrator.mjINT_RK4, "mujoco_rk4")]:
            for h_ms in (1.0, 0.5, 0.25):
                print(json.dumps(run(int(robot), path, seconds, integrator, name, h_ms)))


if __name__ == "__main__":
    main()
