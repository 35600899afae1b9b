"""Independent reference: does a MuJoCo model written by `dynforge identify --mjcf` hold the calibrated robot?

MuJoCo's inverse dynamics of the MJCF (qfrc_inverse; contacts, limits and frictionloss off, so that the joint's
Coulomb friction, a constraint in MuJoCo, is compared on its own) against Pinocchio's of the calibrated URDF plus each
joint's rotor inertia times its acceleration and its viscous friction times its velocity, both from identify's JSON,
at random states of the identified joints (the welded ones where the harness holds them, the middle of their range). Also that the MJCF's frictionloss is the JSON's Coulomb friction and that
its `offset` numeric holds the JSON's offsets.

stdin (JSON): {"mjcf", "urdf", "json" (paths), "states", "seed"}.
stdout (JSON): {"relative": max |tau_mujoco - tau_reference| / max |tau_reference|, "coulomb": max |difference|,
"offset": max |difference|, "joints": n}.
"""
import json
import sys

import mujoco
import numpy as np
import pinocchio


def main() -> None:
    req = json.load(sys.stdin)
    result = json.load(open(req["json"]))
    joints = [j["name"] for j in result["joints"]]
    m = mujoco.MjModel.from_xml_path(req["mjcf"])
    m.opt.disableflags |= (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
                           | mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
    d = mujoco.MjData(m)
    pin = pinocchio.buildModelFromUrdf(req["urdf"])
    data = pin.createData()
    rng = np.random.default_rng(req["seed"])
    worst, scale = 0.0, 0.0
    for _ in range(req["states"]):
        q, qd, qdd = (rng.uniform(-1.5, 1.5, len(joints)) for _ in range(3))
        reference = np.zeros(len(joints))
        pq, pv, pa = np.zeros(pin.nq), np.zeros(pin.nv), np.zeros(pin.nv)
        # Joints identify welded (a gripper held still) sit where the harness holds them: the middle of their range.
        for jid in range(1, pin.njoints):
            if pin.names[jid] not in joints and pin.nqs[jid] == 1:
                lo, hi = pin.lowerPositionLimit[pin.idx_qs[jid]], pin.upperPositionLimit[pin.idx_qs[jid]]
                pq[pin.idx_qs[jid]] = 0.5 * (lo + hi) if np.isfinite(lo + hi) else 0.0
        for k, name in enumerate(joints):
            jid = pin.getJointId(name)
            pq[pin.idx_qs[jid]], pv[pin.idx_vs[jid]], pa[pin.idx_vs[jid]] = q[k], qd[k], qdd[k]
            jm = m.joint(name)
            d.qpos[jm.qposadr[0]], d.qvel[jm.dofadr[0]], d.qacc[jm.dofadr[0]] = q[k], qd[k], qdd[k]
        tau = pinocchio.rnea(pin, data, pq, pv, pa)
        for k, name in enumerate(joints):
            j = result["joints"][k]
            reference[k] = (tau[pin.idx_vs[pin.getJointId(name)]] + j["armature"]["value"] * qdd[k]
                            + j["viscous"]["value"] * qd[k])
        mujoco.mj_inverse(m, d)
        got = np.array([d.qfrc_inverse[m.joint(name).dofadr[0]] for name in joints])
        worst = max(worst, float(np.abs(got - reference).max()))
        scale = max(scale, float(np.abs(reference).max()))
    coulomb = max(abs(m.dof_frictionloss[m.joint(j["name"]).dofadr[0]] - j["coulomb"]["value"])
                  for j in result["joints"])
    offsets = m.numeric("offset").data if m.nnumeric else np.zeros(0)
    offset = max(abs(o - j["offset"]["value"]) for o, j in zip(offsets, result["joints"], strict=True))
    json.dump({"relative": worst / scale, "coulomb": float(coulomb), "offset": float(offset), "joints": len(joints)},
              sys.stdout)


if __name__ == "__main__":
    main()
