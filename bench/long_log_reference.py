"""The reference beside `dynforge identify` on a long log (bench/src/long_log.rs): the classical least-squares
identification of the same bag with the official MCAP reader and Pinocchio. The joint states are decoded, velocity and
acceleration come from central differences of the positions smoothed by a 21-sample moving average (numpy has no
Butterworth filter), Pinocchio's joint torque regressor plus Coulomb and viscous columns is evaluated at every sample
and accumulated into the normal equations chunk by chunk, and the least-squares problem is solved (numpy lstsq on the
normal equations). Prints each phase's time.

Usage: python long_log_reference.py BAG_DIR URDF [--minutes M]   (M: only the first M minutes, then extrapolated)
"""
import glob
import os
import sys
import time

import numpy as np
import pinocchio as pin
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def read(bag, limit):
    names, t, q, tau = None, [], [], []
    for path in sorted(glob.glob(os.path.join(bag, "*.mcap")), key=lambda p: int(p.rsplit("_", 1)[1].split(".")[0])):
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, msg in reader.iter_decoded_messages(topics=["/joint_states"]):
                names = list(msg.name)
                t.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
                q.append(msg.position)
                tau.append(msg.effort)
                if len(t) >= limit:
                    return names, np.array(t), np.array(q), np.array(tau)
    return names, np.array(t), np.array(q), np.array(tau)


def main():
    bag, urdf = sys.argv[1], sys.argv[2]
    minutes = float(sys.argv[sys.argv.index("--minutes") + 1]) if "--minutes" in sys.argv else None
    limit = int(minutes * 60_000) if minutes else 1 << 62
    start = time.perf_counter()
    names, t, q, tau = read(bag, limit)
    t_read = time.perf_counter() - start

    full = pin.buildModelFromUrdf(urdf)
    lock = [full.getJointId(j) for j in full.names if j not in names and j != "universe"]
    model = pin.buildReducedModel(full, lock, pin.neutral(full))
    data = model.createData()
    order = [names.index(model.names[j]) for j in range(1, model.njoints)]
    q, tau = q[:, order], tau[:, order]
    n, dt = model.nv, np.median(np.diff(t))

    start = time.perf_counter()
    kernel = np.ones(21) / 21
    qs = np.column_stack([np.convolve(q[:, j], kernel, mode="same") for j in range(n)])
    qd = np.gradient(qs, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    p = 10 * n + 2 * n
    a, b, count = np.zeros((p, p)), np.zeros(p), 0
    chunk = 10_000
    for lo in range(20, len(t) - 20, chunk):
        hi = min(lo + chunk, len(t) - 20)
        rows = np.zeros(((hi - lo) * n, p))
        for k in range(lo, hi):
            y = pin.computeJointTorqueRegressor(model, data, qs[k], qd[k], qdd[k])
            r = (k - lo) * n
            rows[r:r + n, :10 * n] = y
            rows[r:r + n, 10 * n::2] = np.diag(np.sign(qd[k]))
            rows[r:r + n, 10 * n + 1::2] = np.diag(qd[k])
        a += rows.T @ rows
        b += rows.T @ tau[lo:hi].reshape(-1)
        count += hi - lo
    t_rows = time.perf_counter() - start

    start = time.perf_counter()
    x, *_ = np.linalg.lstsq(a, b, rcond=1e-10)
    t_solve = time.perf_counter() - start
    rss = max(0.0, x @ a @ x - 2 * b @ x + tau[20:len(t) - 20].reshape(-1) @ tau[20:len(t) - 20].reshape(-1))
    nrmse = np.sqrt(rss / (count * n)) / tau.std()
    total = t_read + t_rows + t_solve
    label = f"{len(t)} samples" + (f" (first {minutes} min)" if minutes else "")
    print(f"reference (Pinocchio regressor + numpy least squares, Python): {label} of {n} joints: read {t_read:.1f} s, "
          f"filter + regressor + normal equations {t_rows:.1f} s, solve {t_solve:.3f} s; {total:.1f} s in all, "
          f"{1e6 * total / len(t):.1f} us per sample; fit NRMSE {nrmse:.4f}")


main()
