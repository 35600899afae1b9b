"""Independent least-squares reference for the real-UR10e identification benchmark.

What: identify a rigid-body + drive model of a real UR10e from four identification logs of the public UR10e dataset
and report its torque prediction error on a held-out point-to-point validation log. The model per joint j is

    tau_j = Y_rnea(q, qd, qdd)_j . pi  +  Ia_j qdd_j  +  Fc_j tanh(qd_j / eps)  +  Fv_j qd_j  +  off_j

with pi the 10 inertial parameters per link (Pinocchio's computeJointTorqueRegressor), Ia the rotor inertia, Fc/Fv the
Coulomb/viscous friction and off a constant torque offset.

Why: it is a deliberately plain, numpy + Pinocchio only baseline (no scipy) to check other identification code
against, so every step is spelled out:
  1. Each log is trimmed to its given 1-based inclusive line range (the CSVs have no header row; torn rows with fewer
     than 19 columns are skipped), resampled onto a uniform grid at the log's median stamp interval (10 ms; inside the
     used ranges a third of the intervals are 8-16 ms) by linear interpolation of q and of torque = gain * current.
  2. q and torque both go through the same zero-phase 4th-order Butterworth low pass (two biquads, forward-backward),
     so they see the same (zero) delay and the same attenuation; qd and qdd are central differences of filtered q.
     The logged velocity columns are not used. A few samples at each end are dropped to discard filter edges.
     Default cut-off 5 Hz: the identification trajectories are Fourier series up to ~0.4-0.6 Hz, the validation
     point-to-point moves have acceleration ramps that want a few Hz, and double differentiation multiplies noise by
     (2 pi f)^2; 2, 3 and 5 Hz give nearly the same held-out error, 8 Hz and above degrade joint 5.
  3. Coulomb friction uses a smoothed sign, tanh(qd / eps) with eps = 0.01 rad/s (--coulomb-eps 0 gives the plain
     sign). Smoothing matters on the validation log: joint 6 stands still for ~56 % of it and joint 5 for ~15 %, and
     there a plain sign of the filtered velocity flips with noise between +-Fc (~2.4 N m on joint 6), while the
     measured torque sits anywhere inside the stiction band. In the *identification* system the row of joint j is
     dropped at samples where |qd_j| < 0.01 rad/s (stiction: torque not determined by the model); the other joints'
     rows at that sample are kept. Validation keeps every sample, so the held-out figure is over the whole log.
  4. Ordinary least squares on the stacked logs with numpy lstsq (columns scaled to unit norm, rcond 1e-9): the
     min-norm solution in scaled coordinates is a valid base-parameter solution, and predictions do not depend on the
     choice inside the null space. The rotor inertia of joint 1 has exactly the same column as link 1's Izz (joint 1
     axis is fixed in the world), and that of joint 2 the same column as link 2's Iyy (its inertia about the joint 2
     axis, which is perpendicular to joint 1), so for those two only the sums are identifiable; lstsq splits them
     (equally, after column scaling), and we print both parts and the sum.
  5. Held-out NRMSE per joint = RMS(error)/std(measured torque), its mean over joints, and the pooled figure
     sqrt(sum of squared errors / sum_j n var_j), for (a) the full model, (b) the same without rotor inertia and offset
     columns, (c) the URDF as given (its inertials via pinocchio.rnea, no friction, no rotor inertia) and (d) the
     repository's own published identification (UR10E_parameters.txt: pi_rgd, per link [Ixx Ixy Ixz Iyy Iyz Izz,
     m c, m] about the link frame's origin, as its generate_rb_regressor.m orders them; pi_drvs, the rotor inertias;
     pi_frcn, per joint [viscous, Coulomb, offset] as its linearFrictionModel.m) through the same regressor; with
     --calibrated, (e) `dynforge identify`'s calibration: its URDF's inertials through pinocchio.rnea plus the JSON's
     rotor inertia, Coulomb, viscous and offset per joint, Coulomb as in (a): one measure for all.

Usage: python bench/ur10e_least_squares.py CHECKOUT_DIR [--cutoff HZ] [--coulomb-eps RAD_S] [--json FILE]
                                            [--calibrated URDF JSON]
       (CHECKOUT_DIR contains dataset_ur10e/ and URe/urdf/ur10e.urdf)
"""
import argparse
import json
import os

import numpy as np
import pinocchio as pin

GAINS = np.array([10.0000, 10.6956, 8.4566, 9.0029, 9.4800, 10.1232])  # N m / A, motor current -> joint torque
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
IDENT = [("identification_data/ur-20_02_10-30sec_12harm.csv", 635, 3510),
         ("identification_data/ur-20_02_12-40sec_12harm.csv", 500, 4460),
         ("identification_data/ur-20_02_05-20sec_8harm.csv", 320, 2310),
         ("identification_data/ur-20_02_12-50sec_12harm.csv", 355, 5090)]
VALID = ("validation_data/ur-20_01_17-ptp_10_points.csv", 700, 4200)
EDGE = 50        # samples dropped at each end after filtering (0.5 s at 10 ms)
STILL = 0.01     # rad/s, below this a joint's row is left out of the identification system


def read_log(path, first, last):
    """Lines first..last (1-based, inclusive) of a header-less CSV -> t, q (n x 6), torque (n x 6). Skips torn rows."""
    rows = []
    with open(path) as f:
        for number, line in enumerate(f, 1):
            if number < first:
                continue
            if number > last:
                break
            cells = line.strip().split(",")
            if len(cells) >= 19:
                try:
                    rows.append([float(c) for c in cells[:19]])
                except ValueError:
                    pass
    a = np.array(rows)
    return a[:, 0], a[:, 1:7], a[:, 13:19] * GAINS


def biquad(x, b, a):
    """One 2nd-order section (direct form II transposed) along axis 0, started in steady state at x[0]."""
    y = np.empty_like(x)
    z2 = (b[2] - a[2]) * x[0]
    z1 = (b[1] - a[1]) * x[0] + z2
    for k in range(len(x)):
        y[k] = b[0] * x[k] + z1
        z1, z2 = b[1] * x[k] - a[1] * y[k] + z2, b[2] * x[k] - a[2] * y[k]
    return y


def butter4_filtfilt(x, cutoff, dt):
    """Zero-phase low pass: 4th-order Butterworth (bilinear transform, pre-warped) run forward then backward."""
    k = np.tan(np.pi * cutoff * dt)
    sections = []
    for q_factor in (1 / (2 * np.cos(np.pi / 8)), 1 / (2 * np.cos(3 * np.pi / 8))):  # the two Butterworth pole pairs
        norm = 1 + k / q_factor + k * k
        b = np.array([k * k, 2 * k * k, k * k]) / norm
        a = np.array([1.0, 2 * (k * k - 1), 1 - k / q_factor + k * k]) / norm
        sections.append((b, a))
    pad = min(len(x) - 1, int(3 / (cutoff * dt)))  # odd reflection at both ends to tame start-up transients
    y = np.concatenate([2 * x[0] - x[pad:0:-1], x, 2 * x[-1] - x[-2:-pad - 2:-1]])
    for _ in range(2):
        for b, a in sections:
            y = biquad(y, b, a)
        y = y[::-1]
    return y[pad:pad + len(x)]


def prepare(root, entry, cutoff):
    """Read, resample on a uniform grid, filter, differentiate, drop the edges -> q, qd, qdd, tau."""
    t, q, tau = read_log(os.path.join(root, "dataset_ur10e", entry[0]), entry[1], entry[2])
    keep = np.concatenate([[True], np.diff(t) > 0])  # guard against repeated stamps
    t, q, tau = t[keep], q[keep], tau[keep]
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], dt)
    q = np.stack([np.interp(grid, t, q[:, j]) for j in range(6)], axis=1)
    tau = np.stack([np.interp(grid, t, tau[:, j]) for j in range(6)], axis=1)
    q, tau = butter4_filtfilt(q, cutoff, dt), butter4_filtfilt(tau, cutoff, dt)
    qd = np.gradient(q, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    cut = slice(EDGE, len(grid) - EDGE)
    return q[cut], qd[cut], qdd[cut], tau[cut], dt


class Regressor:
    """Pinocchio rigid-body regressor mapped onto the six CSV joints by name, plus per-joint drive columns."""

    def __init__(self, urdf, coulomb_eps):
        self.eps = coulomb_eps
        self.model = pin.buildModelFromUrdf(urdf)
        self.data = self.model.createData()
        ids = [self.model.getJointId(name) for name in JOINTS]
        self.iq = [self.model.joints[i].idx_q for i in ids]
        self.iv = [self.model.joints[i].idx_v for i in ids]
        self.cols = np.concatenate([np.arange(10 * (i - 1), 10 * i) for i in ids])  # links of the six joints

    def full_state(self, q, qd, qdd):
        Q, V, A = pin.neutral(self.model), np.zeros(self.model.nv), np.zeros(self.model.nv)
        Q[self.iq], V[self.iv], A[self.iv] = q, qd, qdd
        return Q, V, A

    def rows(self, q, qd, qdd):
        """Per sample: a 6 x (60 + 24) block; drive columns per joint are [rotor inertia, Coulomb, viscous, offset]."""
        out = np.zeros((len(q), 6, 60 + 24))
        for n in range(len(q)):
            Y = pin.computeJointTorqueRegressor(self.model, self.data, *self.full_state(q[n], qd[n], qdd[n]))
            out[n, :, :60] = Y[np.ix_(self.iv, self.cols)]
        coulomb = np.tanh(qd / self.eps) if self.eps > 0 else np.sign(qd)
        for j in range(6):
            out[:, j, 60 + 4 * j:64 + 4 * j] = np.stack([qdd[:, j], coulomb[:, j], qd[:, j], np.ones(len(q))], 1)
        return out

    def urdf_torque(self, q, qd, qdd, model=None):
        model = model or self.model
        data = model.createData()
        return np.array([pin.rnea(model, data, *self.full_state(*s))[self.iv] for s in zip(q, qd, qdd)])

    def calibrated_torque(self, urdf, result, q, qd, qdd):
        """`dynforge identify`'s prediction: the calibrated URDF's rigid bodies plus its JSON `result`'s drive terms."""
        tau = self.urdf_torque(q, qd, qdd, pin.buildModelFromUrdf(urdf))
        coulomb = np.tanh(qd / self.eps) if self.eps > 0 else np.sign(qd)
        for joint in result["joints"]:
            j = JOINTS.index(joint["name"])
            value = {k: joint[k]["value"] for k in ("armature", "coulomb", "viscous", "offset")}
            tau[:, j] += (value["armature"] * qdd[:, j] + value["coulomb"] * coulomb[:, j]
                          + value["viscous"] * qd[:, j] + value["offset"])
        return tau


def published(checkout):
    """The repository's published parameters (UR10E_parameters.txt) as this script's 84 columns, or None without
    the file: per link Pinocchio's [m, mc, Ixx Ixy Iyy Ixz Iyz Izz], per joint [rotor inertia, Coulomb, viscous,
    offset]."""
    path = os.path.join(checkout, "UR10E_parameters.txt")
    if not os.path.exists(path):
        return None
    values = {}
    for line in open(path, encoding="utf-8"):
        name, _, rest = line.partition("=")
        if rest.strip().startswith("["):
            values[name.strip()] = np.array([float(v) for v in rest.strip().strip("[]").split()])
    x = np.zeros(84)
    for k, link in enumerate(values["pi_rgd"].reshape(6, 10)):
        ixx, ixy, ixz, iyy, iyz, izz, hx, hy, hz, m = link
        x[10 * k:10 * k + 10] = [m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz]
    for j, (viscous, coulomb, offset) in enumerate(values["pi_frcn"].reshape(6, 3)):
        x[60 + 4 * j:64 + 4 * j] = [values["pi_drvs"][j], coulomb, viscous, offset]
    return x


def solve(A, b):
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    x, _, rank, _ = np.linalg.lstsq(A / scale, b, rcond=1e-9)
    return x / scale, rank


def nrmse(tau, pred):
    err = pred - tau
    per_joint = np.sqrt((err ** 2).mean(0)) / tau.std(0)
    pooled = np.sqrt((err ** 2).sum() / (len(tau) * tau.var(0)).sum())
    return {"per_joint": per_joint.tolist(), "mean": float(per_joint.mean()), "pooled": float(pooled)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkout")
    ap.add_argument("--cutoff", type=float, default=5.0, help="low-pass cut-off [Hz] for q and torque (default 5)")
    ap.add_argument("--coulomb-eps", type=float, default=0.01,
                    help="Coulomb column tanh(qd/eps) [rad/s]; 0 for plain sign (default 0.01)")
    ap.add_argument("--json", help="write the numbers to this file")
    ap.add_argument("--calibrated", nargs=2, metavar=("URDF", "JSON"),
                    help="also score `dynforge identify`'s calibrated URDF and its --json output")
    args = ap.parse_args()
    reg = Regressor(os.path.join(args.checkout, "URe", "urdf", "ur10e.urdf"), args.coulomb_eps)

    blocks, targets = [], []
    for entry in IDENT:
        q, qd, qdd, tau, dt = prepare(args.checkout, entry, args.cutoff)
        moving = np.abs(qd) >= STILL  # n x 6: keep joint j's row only where joint j moves
        blocks.append(reg.rows(q, qd, qdd)[moving])
        targets.append(tau[moving])
        print(f"{entry[0]}: {len(q)} samples at dt {dt * 1e3:.1f} ms, {moving.sum()} of {moving.size} rows kept")
    A, b = np.concatenate(blocks), np.concatenate(targets)
    drive = np.arange(60, 84).reshape(6, 4)
    reduced = np.concatenate([np.arange(60), drive[:, 1:3].ravel()])  # (b): no rotor inertia, no offset
    x_full, rank_full = solve(A, b)
    x_red, rank_red = solve(A[:, reduced], b)
    print(f"identification: {A.shape[0]} rows; rank {rank_full} of {A.shape[1]} (full), {rank_red} of {len(reduced)}"
          f" (no rotor inertia/offset); cut-off {args.cutoff} Hz, Coulomb eps {args.coulomb_eps} rad/s")

    q, qd, qdd, tau, dt = prepare(args.checkout, VALID, args.cutoff)
    R = reg.rows(q, qd, qdd)
    results = {"cutoff_hz": args.cutoff, "coulomb_eps": args.coulomb_eps, "validation_samples": len(q),
               "least_squares": nrmse(tau, R @ x_full),
               "least_squares_no_rotor_no_offset": nrmse(tau, R[:, :, reduced] @ x_red),
               "urdf": nrmse(tau, reg.urdf_torque(q, qd, qdd))}
    x_published = published(args.checkout)
    if x_published is not None:
        results["published"] = nrmse(tau, R @ x_published)
    if args.calibrated:
        urdf, result = args.calibrated[0], json.load(open(args.calibrated[1]))
        results["identify"] = nrmse(tau, reg.calibrated_torque(urdf, result, q, qd, qdd))
    print(f"\nheld-out NRMSE on {VALID[0]} ({len(q)} samples)      per joint 1..6                       mean  pooled")
    for key in ("identify", "least_squares", "least_squares_no_rotor_no_offset", "published", "urdf"):
        if key not in results:
            continue
        r = results[key]
        print(f"  {key:34s} " + " ".join(f"{v:.3f}" for v in r["per_joint"]) + f"   {r['mean']:.3f}  {r['pooled']:.3f}")

    d = x_full[drive]
    twins = {0: x_full[9], 1: x_full[16]}  # link 1 Izz, link 2 Iyy: the same columns as rotor inertias 1 and 2
    results["drive"] = {name: dict(zip(["rotor_inertia", "coulomb", "viscous", "offset"], map(float, d[j])))
                        for j, name in enumerate(JOINTS)}
    results["joint1_rotor_plus_link1_izz"] = float(d[0, 0] + twins[0])
    results["joint2_rotor_plus_link2_iyy"] = float(d[1, 0] + twins[1])
    print("\nidentified drive parameters (full model)\n  joint                rotor inertia [kg m^2]  Coulomb [N m]"
          "  viscous [N m s/rad]  offset [N m]")
    for j, name in enumerate(JOINTS):
        print(f"  {name:20s} {d[j, 0]:12.4f}  {d[j, 1]:18.3f}  {d[j, 2]:14.3f}  {d[j, 3]:16.3f}")
    for j, link in ((0, "link 1 Izz"), (1, "link 2 Iyy")):
        print(f"  joint {j + 1} rotor inertia is not separable from {link} (identical columns): lstsq gives"
              f" {d[j, 0]:.4f} + {twins[j]:.4f}; only the sum {d[j, 0] + twins[j]:.4f} kg m^2 is identified")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
