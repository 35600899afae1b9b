"""Microseconds per call of Pinocchio's rnea, aba, crba and joint-torque regressor called from Python on a URDF (the reference side of
bench/dynamics.sh). Same protocol as dynforge-bench-dynamics: 1000 random states cycled, median of 7 runs."""
import json
import sys
import time

import numpy as np
import pinocchio as pin

STATES, REPEATS = 1000, 7


def time_per_call(calls, f):
    runs = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        for k in range(calls):
            f(k % STATES)
        runs.append((time.perf_counter() - start) * 1e6 / calls)
    return sorted(runs)[REPEATS // 2]


def main():
    path, calls = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 50_000
    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    rng = np.random.default_rng(0)
    n = model.nq
    q, qd = rng.uniform(-3, 3, (STATES, n)), rng.uniform(-2, 2, (STATES, n))
    qdd, tau = rng.uniform(-5, 5, (STATES, n)), rng.uniform(-20, 20, (STATES, n))
    result = {
        "dof": n,
        "calls": calls,
        "rnea_us": time_per_call(calls, lambda k: pin.rnea(model, data, q[k], qd[k], qdd[k])),
        "aba_us": time_per_call(calls, lambda k: pin.aba(model, data, q[k], qd[k], tau[k])),
        "crba_us": time_per_call(calls, lambda k: pin.crba(model, data, q[k])),
        "regressor_us": time_per_call(
            calls, lambda k: pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        ),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
