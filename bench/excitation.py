"""Independent check of `dynforge excite` against random multi-sines within the same limits.

What: scores a designed excitation set (the `excitation-K.json` Fourier series `excite` writes) and random multi-sines
built the usual way, all on the same robot, by the covariance of its base parameters, and prints both criteria
(covariance trace, and the mean log eigenvalue of the information, i.e. log det per dimension) for
  - each designed trajectory alone, and the set together;
  - the best and the median of `--draws` random multi-sines alone, and of `--draws` random sets of as many
    multi-sines as the design has trajectories.

How, spelled out so it shares nothing with the Rust code but the definitions:
  1. The robot is the URDF read by Pinocchio, the `--fix` joints and those that mimic them locked at 0 (the Panda's
     fingers).
  2. Information: per sample (at `--rate`, 1 kHz by default) Pinocchio's joint-torque regressor plus per joint a
     Coulomb column sign(qd) and a viscous column qd; columns scaled to the robot's own magnitudes (per link: mass m,
     m L for first moments and m L^2 for second moments, L the larger of the COM's distance from the joint, the radius
     of gyration and 2 cm; friction 5 % of the effort limit, and of effort over velocity limit), W = sum Y^T Y.
     The base subspace is the range of the sum of every motion's W (eigenvalues above 1e-10 of the largest); each
     motion's W is restricted to it: trace of its inverse (covariance at unit noise) and mean log eigenvalue.
  3. A random multi-sine, per joint: 5 frequencies uniform in 0.1-1 Hz, uniform phases, amplitudes 1/omega, times a
     quintic fade-in and fade-out (`--fade` s) so it starts and ends at rest at the design's start pose. Each joint is
     scaled alone until the first of these binds: 95 % of the design's speed bound (velocity share x URDF limit), 96 %
     of its room from the start pose to the range less the margin (either side), the acceleration limit. Then all
     joints are scaled down together (by 3 % steps) until the effort (Pinocchio's RNEA with the URDF's friction and
     damping) is within the effort share of the URDF's limits at every sample.
Self-collision is not checked for the multi-sines (the design is checked): this favours the baseline.

argv: see --help. Prints a markdown table; --json writes the figures.
"""
import argparse
import glob
import json
import math
import os
import re
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

FREQUENCIES = 5
BAND = (0.1, 1.0)


def robot(urdf, fixed):
    """The URDF's model with the `fixed` joints, and the joints that mimic them (as excite welds them), locked at 0."""
    model = pin.buildModelFromUrdf(urdf)
    mimics = [(j.get("name"), j.find("mimic").get("joint")) for j in ET.parse(urdf).getroot().iter("joint") if j.find("mimic") is not None]
    fixed = fixed + [name for name, leader in mimics if leader in fixed and name not in fixed]
    if fixed:
        ids = [model.getJointId(name) for name in fixed]
        missing = [name for name, i in zip(fixed, ids) if i >= model.njoints]
        if missing:
            sys.exit(f"{urdf}: no joint named {missing}")
        model = pin.buildReducedModel(model, ids, pin.neutral(model))
    if model.nq != model.nv:
        sys.exit(f"{urdf}: a joint with nq != nv (continuous?) is not handled")
    return model


def scales(model):
    s = []
    for i in range(1, model.njoints):
        p = model.inertias[i].toDynamicParameters()
        m = max(abs(p[0]), 1e-3)
        com = np.linalg.norm(p[1:4]) / m
        gyration = math.sqrt(abs(p[4] + p[6] + p[9]) / (2 * m))
        length = max(com, gyration, 0.02)
        s += [m] + [m * length] * 3 + [m * length * length] * 6
    for j in range(model.nv):
        effort, velocity = model.effortLimit[j], model.velocityLimit[j]
        s += [0.05 * effort, 0.05 * effort / max(velocity, 1e-3)]
    return np.array(s)


class Scorer:
    def __init__(self, model, args):
        self.model, self.data = model, model.createData()
        self.scales = scales(model)
        self.rate = args.rate
        n = model.nv
        lo, hi = model.lowerPositionLimit, model.upperPositionLimit
        margin = args.margin * (hi - lo)
        self.lower, self.upper = lo + margin, hi - margin
        self.speed = args.velocity_share * model.velocityLimit
        self.acceleration = np.full(n, args.acceleration)
        self.effort = args.effort_share * model.effortLimit
        self.friction, self.damping = np.array(model.friction), np.array(model.damping)

    def information(self, q, qd, qdd):
        rows = []
        for k in range(len(q)):
            y = pin.computeJointTorqueRegressor(self.model, self.data, q[k], qd[k], qdd[k])
            rows.append(np.hstack([y, np.zeros((self.model.nv, 2 * self.model.nv))]))
            for j in range(self.model.nv):
                rows[-1][j, y.shape[1] + 2 * j] = np.sign(qd[k][j])
                rows[-1][j, y.shape[1] + 2 * j + 1] = qd[k][j]
        y = np.vstack(rows) * self.scales
        return y.T @ y

    def effort_share(self, q, qd, qdd):
        worst = 0.0
        for k in range(len(q)):
            tau = pin.rnea(self.model, self.data, q[k], qd[k], qdd[k])
            tau = tau + self.friction * np.sign(qd[k]) + self.damping * qd[k]
            worst = max(worst, np.max(np.abs(tau) / self.effort))
        return worst

    def kinematic_peaks(self, start, q, qd, qdd):
        """Per joint the largest share of its position room, speed and acceleration bounds reached."""
        d = q - start
        room = np.where(d >= 0, self.upper - start, start - self.lower)
        return np.max(np.abs(d) / room, axis=0), np.max(np.abs(qd) / self.speed, axis=0), np.max(
            np.abs(qdd) / self.acceleration, axis=0
        )


def fourier(series, t):
    """The design's series (`proto/src/fourier.rs`'s form) at times t."""
    w = 2 * math.pi / series["period"]
    n = len(series["start"])
    q = np.tile(np.array(series["start"], dtype=float), (len(t), 1))
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    for j in range(n):
        for l, (a, b) in enumerate(zip(series["a"][j], series["b"][j])):
            wl = w * (l + 1)
            s, c = np.sin(wl * t), np.cos(wl * t)
            q[:, j] += (a * s + b * (1 - c)) / wl
            qd[:, j] += a * c + b * s
            qdd[:, j] += wl * (b * c - a * s)
    return q, qd, qdd


def fade(t, duration, width):
    """Quintic window rising from 0 to 1 over `width` s and back at the end, with its two derivatives."""

    def smooth(x):
        x = np.clip(x, 0.0, 1.0)
        return 10 * x**3 - 15 * x**4 + 6 * x**5, (30 * x**2 - 60 * x**3 + 30 * x**4), (60 * x - 180 * x**2 + 120 * x**3)

    a, da, dda = smooth(t / width)
    b, db, ddb = smooth((duration - t) / width)
    inside_a = (t > 0) & (t < width)
    inside_b = (t > duration - width) & (t < duration)
    da, dda = da * inside_a / width, dda * inside_a / width**2
    db, ddb = -db * inside_b / width, ddb * inside_b / width**2
    return a * b, da * b + a * db, dda * b + 2 * da * db + a * ddb


def multisine(scorer, start, duration, fade_width, rng, t):
    n = len(start)
    window, dwindow, ddwindow = fade(t, duration, fade_width)
    s, ds, dds = np.zeros((len(t), n)), np.zeros((len(t), n)), np.zeros((len(t), n))
    for j in range(n):
        omega = 2 * math.pi * rng.uniform(*BAND, FREQUENCIES)
        phase = rng.uniform(0, 2 * math.pi, FREQUENCIES)
        for w, p in zip(omega, phase):
            s[:, j] += np.sin(w * t + p) / w
            ds[:, j] += np.cos(w * t + p)
            dds[:, j] -= w * np.sin(w * t + p)
    w0, w1, w2 = window[:, None], dwindow[:, None], ddwindow[:, None]
    d, dd, ddd = w0 * s, w1 * s + w0 * ds, w2 * s + 2 * w1 * ds + w0 * dds
    position, speed, acceleration = scorer.kinematic_peaks(start, start + d, dd, ddd)
    scale = np.minimum(np.minimum(0.96 / position, 0.95 / speed), 1.0 / acceleration)
    for _ in range(200):
        q, qd, qdd = start + scale * d, scale * dd, scale * ddd
        if scorer.effort_share(q[::5], qd[::5], qdd[::5]) <= 1.0 and scorer.effort_share(q, qd, qdd) <= 1.0:
            return q, qd, qdd
        scale = 0.97 * scale
    sys.exit("a multi-sine could not be scaled into the effort limits")


def quality(base, w):
    e = np.linalg.eigvalsh(base.T @ w @ base)
    e = np.maximum(e, np.finfo(float).tiny)
    return {"trace": float(np.sum(1 / e)), "log_det": float(np.mean(np.log(e)))}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--urdf", required=True)
    parser.add_argument("--design", required=True, help="directory with excite's excitation-K.json")
    parser.add_argument("--fix", action="append", default=[], help="joint to lock at 0 (repeatable)")
    parser.add_argument("--acceleration", type=float, default=5.0)
    parser.add_argument("--velocity-share", type=float, default=0.8)
    parser.add_argument("--effort-share", type=float, default=0.8)
    parser.add_argument("--margin", type=float, default=0.05)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--fade", type=float, default=1.0, help="fade-in and fade-out of the multi-sines [s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json")
    args = parser.parse_args()

    model = robot(args.urdf, args.fix)
    scorer = Scorer(model, args)
    members = [(re.fullmatch(r"excitation-(\d+)\.json", os.path.basename(p)), p) for p in glob.glob(os.path.join(args.design, "*.json"))]
    paths = [p for m, p in sorted((int(m.group(1)), p) for m, p in members if m)]
    designs = [json.load(open(p))["series"] for p in paths]
    if not designs:
        sys.exit(f"{args.design}: no excitation-K.json")
    names = [model.names[i] for i in range(1, model.njoints)]
    joints = json.load(open(paths[0]))["joints"]
    if joints != names:
        sys.exit(f"{args.design}: joints {joints} are not the model's {names}")
    duration, start = designs[0]["period"], np.array(designs[0]["start"])
    t = np.arange(int(round(duration * args.rate)) + 1) / args.rate

    designed = [scorer.information(*fourier(s, t)) for s in designs]
    rng = np.random.default_rng(args.seed)
    singles = [scorer.information(*multisine(scorer, start, duration, args.fade, rng, t)) for _ in range(args.draws)]
    sets = [
        sum(scorer.information(*multisine(scorer, start, duration, args.fade, rng, t)) for _ in range(len(designs)))
        for _ in range(args.draws)
    ]
    total = sum(designed) + sum(singles) + sum(sets)
    e, v = np.linalg.eigh(total)
    base = v[:, e > 1e-10 * e.max()]

    def summary(ws):
        qs = [quality(base, w) for w in ws]
        by_trace = sorted(q["trace"] for q in qs)
        by_det = sorted((q["log_det"] for q in qs), reverse=True)
        return {
            "best": {"trace": by_trace[0], "log_det": by_det[0]},
            "median": {"trace": float(np.median(by_trace)), "log_det": float(np.median(by_det))},
        }

    result = {
        "rank": base.shape[1],
        "parameters": len(scorer.scales),
        "alone": [quality(base, w) for w in designed],
        "set": quality(base, sum(designed)),
        "multisine": summary(singles),
        "multisine_sets": summary(sets),
    }
    print(f"{args.urdf}: {base.shape[1]} of {len(scorer.scales)} base parameters, {args.draws} draws\n")
    print("| motion | covariance trace | mean log eigenvalue | trace: x smaller than best / median multi-sine | "
          "det: x larger than best / median (per dimension) |")
    print("|---|---:|---:|---:|---:|")

    def row(name, q, ref):
        ratio = lambda r: r["trace"] / q["trace"]
        det = lambda r: math.exp(q["log_det"] - r["log_det"])
        print(f"| {name} | {q['trace']:.3e} | {q['log_det']:.3f} | {ratio(ref['best']):.2f} / {ratio(ref['median']):.2f} "
              f"| {det(ref['best']):.2f} / {det(ref['median']):.2f} |")

    for k, q in enumerate(result["alone"]):
        row(f"designed trajectory {k}", q, result["multisine"])
    row("designed set", result["set"], result["multisine_sets"])
    for what, key in [("multi-sine", "multisine"), (f"set of {len(designs)} multi-sines", "multisine_sets")]:
        for which in ["best", "median"]:
            q = result[key][which]
            print(f"| {which} {what} | {q['trace']:.3e} | {q['log_det']:.3f} | | |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
