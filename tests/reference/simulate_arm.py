"""Independent reference: a real arm's log, simulated by MuJoCo and written as a ROS 2 bag (MCAP, /joint_states and
/robot_description) the way a driver publishes it. Used by the tests of `dynforge identify` on example-robot-data's
UR5 and Panda: the robot is the URDF's (its inertials, as MuJoCo reads them), the joints have known Coulomb and
viscous friction, and the log has what real drivers give: an effort convention, a rate, encoder-quantised
positions, velocities from encoder differences or none, effort noise.

stdin (JSON):
  urdf            path of the URDF simulated (its text is also the bag's /robot_description unless "description")
  description     optional: the text written as /robot_description instead
  friction        {joint: [coulomb, viscous]} for the joints that move (the others are held still)
  armature        optional: {joint: rotor inertia reflected through the gearbox} (MuJoCo's dof_armature; default 0)
  offset          optional: {joint: constant torque} added to the logged effort (a torque sensor's bias)
  stribeck        optional: {joint: [torque, velocity]}: friction no Coulomb-viscous model holds, the Stribeck
                  hump torque * exp(-(qd / velocity)^2) * tanh(qd / 0.02) opposing the motion on top of the joint's
                  Coulomb and viscous friction (stiction above the sliding friction at low speed)
  seed            of the reference motion (multi-sines), and of the noise
  excitation      optional: an `excitation-K.json` of `dynforge excite` (a Fourier series per joint) as the reference
                  of the joints it names instead of multi-sines; the duration is its period
  duration        seconds of motion (1 s ramps in and out included)
  rate            log rate [Hz], 100 to 1000
  effort          "held": the logged effort is the torque applied until the next sample (zero-order hold, control at
                  the log rate); "sampled": the torque is updated every simulation step (0.25 ms) and the log samples it
                  at its instants
  noise           effort noise, a fraction of each joint's torque RMS (white, Gaussian); 0 for none
  counts          encoder counts per revolution (0: exact positions); prismatic joints get 1e-6 m steps
  velocity        "measured" (exact), "encoder" (differences of the logged positions), "absent" (no velocity array),
                  "noisy" (measured, plus white noise of velocity_noise times each joint's velocity RMS)
  hold            {joint: position} for joints held still (default: the middle of their limits, or 0)
  out             path of the bag; "split": 2 writes it as a rosbag2 directory of two files (NAME_0.mcap, NAME_1.mcap)
stdout (JSON): {"joints": [...], "samples": n, "torque_rms": [...]}.

Also: `--path ur5|panda` prints that URDF's path; `--perturb` (stdin {"urdf", "seed", "low", "high", "out"}) writes a
"nominal" URDF with every inertial off by a random 20-30 % and no friction; `--load URDF` loads it in MuJoCo and
prints its degrees of freedom and total mass.
"""
import json
import os
import sys

import mujoco
import numpy as np
from mcap_ros2.writer import Writer

JOINT_STATE = "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n" \
    "================================================================================\nMSG: std_msgs/Header\n" \
    "builtin_interfaces/Time stamp\nstring frame_id\n" \
    "================================================================================\nMSG: builtin_interfaces/Time\n" \
    "int32 sec\nuint32 nanosec\n"
STRING = "string data\n"


def mujoco_model(urdf_text):
    """The URDF as MuJoCo loads it for dynamics alone: no geometry (meshes would need their files), inertias as given
    (no balancing, no fusing of static bodies)."""
    import re
    text = re.sub(r"<visual>.*?</visual>|<visual\s[^>]*>.*?</visual>", "", urdf_text, flags=re.S)
    text = re.sub(r"<collision>.*?</collision>|<collision\s[^>]*>.*?</collision>", "", text, flags=re.S)
    text = re.sub(r"<transmission.*?</transmission>|<gazebo.*?</gazebo>", "", text, flags=re.S)
    compiler = '<mujoco><compiler balanceinertia="false" fusestatic="false" discardvisual="true"/></mujoco>'
    text = re.sub(r"(<robot[^>]*>)", r"\1" + compiler, text, count=1)
    return mujoco.MjModel.from_xml_string(text)


def reference(rng, lo, hi, vmax, duration):
    """A multi-sine around the middle of [lo, hi] within 35 % of the range each way and 60 % of the speed limit,
    ramped in and out over 1 s so the motion starts and ends at rest: functions of t giving (q, qd, qdd)."""
    lo, hi = max(lo, -np.pi), min(hi, np.pi)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    freqs = rng.uniform(0.1, 0.8, 5)
    phases = rng.uniform(0, 2 * np.pi, 5)
    weights = rng.uniform(0.5, 1.0, 5)
    amp = 0.35 * half / weights.sum()
    speed = amp * (weights * 2 * np.pi * freqs).sum()
    if speed > 0.6 * vmax:
        amp *= 0.6 * vmax / speed

    def ramp(t):
        # C2 ramp: 0 at t <= 0, 1 at t >= 1 (smootherstep), and its two derivatives.
        s = np.clip(t, 0.0, 1.0)
        w = s**3 * (10 - 15 * s + 6 * s * s)
        dw = 30 * s * s * (1 - s) ** 2 if 0 < t < 1 else 0.0
        ddw = 60 * s * (1 - s) * (1 - 2 * s) if 0 < t < 1 else 0.0
        return w, dw, ddw

    def at(t):
        w = 2 * np.pi * freqs
        x = amp * (weights * np.sin(w * t + phases)).sum()
        dx = amp * (weights * w * np.cos(w * t + phases)).sum()
        ddx = -amp * (weights * w * w * np.sin(w * t + phases)).sum()
        a, da, dda = ramp(t)
        b, db, ddb = ramp(duration - t)
        env, denv, ddenv = a * b, da * b - a * db, dda * b - 2 * da * db + a * ddb
        return centre + env * x, denv * x + env * dx, ddenv * x + 2 * denv * dx + env * ddx

    return at


def fourier(series, j):
    """Joint j of an excitation's Fourier series (proto/src/fourier.rs): a function of t giving (q, qd, qdd)."""
    w = 2 * np.pi / series["period"]
    a, b, q0 = np.array(series["a"][j]), np.array(series["b"][j]), series["start"][j]
    wl = w * np.arange(1, len(a) + 1)

    def at(t):
        s, c = np.sin(wl * t), np.cos(wl * t)
        return q0 + ((a * s + b * (1 - c)) / wl).sum(), (a * c + b * s).sum(), (wl * (b * c - a * s)).sum()

    return at


def simulate(req):
    urdf_text = open(req["urdf"]).read()
    excitation = json.load(open(req["excitation"])) if "excitation" in req else None
    if excitation:
        req["duration"] = excitation["series"]["period"]
    m = mujoco_model(urdf_text)
    d = mujoco.MjData(m)
    rate, duration, effort = req["rate"], req["duration"], req["effort"]
    log_dt = 1.0 / rate
    # 0.25 ms steps at 1 kHz (finer for a log of a slower rate); a sampled effort is updated every step.
    substeps = max(4, int(round(log_dt / 0.00025)))
    sim_dt = log_dt / substeps
    m.opt.timestep = sim_dt
    m.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_LIMIT
    friction = req["friction"]
    joints = [m.joint(j).name for j in range(m.njnt)]
    rng = np.random.default_rng(req["seed"])
    refs = {}
    for j, name in enumerate(joints):
        dof = m.jnt_dofadr[j]
        m.dof_armature[dof] = req.get("armature", {}).get(name, 0.0)
        coulomb, viscous = friction.get(name, [0.0, 0.0])
        m.dof_damping[dof] = viscous
        m.dof_frictionloss[dof] = coulomb
        m.dof_solref[dof] = [2 * sim_dt, 1.0]
        m.dof_solimp[dof] = [0.9999, 0.9999, 0.001, 0.5, 2.0]
        lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-np.pi, np.pi)
        if excitation and name in excitation["joints"]:
            refs[name] = fourier(excitation["series"], excitation["joints"].index(name))
        elif name in friction:
            vmax = 2.0 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE else 0.1
            refs[name] = reference(rng, lo, hi, vmax, duration)
        else:
            held = req.get("hold", {}).get(name, 0.5 * (lo + hi) if m.jnt_limited[j] else 0.0)
            refs[name] = (lambda v: (lambda t: (v, 0.0, 0.0)))(held)
    qadr = [m.jnt_qposadr[j] for j in range(m.njnt)]
    vadr = [m.jnt_dofadr[j] for j in range(m.njnt)]
    stribeck = np.zeros((m.nv, 2))
    stribeck[:, 1] = 1.0
    for j, name in enumerate(joints):
        if name in req.get("stribeck", {}):
            stribeck[vadr[j]] = req["stribeck"][name]

    def hump(qd):
        return stribeck[:, 0] * np.exp(-((qd / stribeck[:, 1]) ** 2)) * np.tanh(qd / 0.02)

    for j, name in enumerate(joints):
        d.qpos[qadr[j]] = refs[name](0.0)[0]
    mujoco.mj_forward(m, d)
    steps = int(round(duration / log_dt))
    control_every = 1 if effort == "sampled" else substeps
    full = np.zeros((m.nv, m.nv))
    omega = 20.0
    log_t, log_q, log_qd, log_tau = [], [], [], []
    tau = np.zeros(m.nv)
    applied = None
    total_substeps = steps * substeps
    per_log = substeps
    for k in range(total_substeps + 1):
        t = k * sim_dt
        if k % control_every == 0:
            mujoco.mj_fullM(m, d, full)
            acc = np.zeros(m.nv)
            for j, name in enumerate(joints):
                q, qd, qdd = refs[name](t)
                e, ed = q - d.qpos[qadr[j]], qd - d.qvel[vadr[j]]
                acc[vadr[j]] = qdd + omega * omega * e + 2 * omega * ed
            tau = full @ acc + d.qfrc_bias
        if k % per_log == 0:
            log_t.append(t)
            log_q.append([d.qpos[a] for a in qadr])
            log_qd.append([d.qvel[a] for a in vadr])
            # Held: the torque applied from now on. Sampled: the torque at this instant, which the simulation's
            # staircase (a step every sim_dt) has half way between the step before and the step after.
            at_instant = tau if effort == "held" or applied is None else 0.5 * (applied + tau)
            offset = req.get("offset", {})
            log_tau.append([at_instant[vadr[j]] + offset.get(name, 0.0) for j, name in enumerate(joints)])
        if k == total_substeps:
            break
        d.qfrc_applied[:] = tau - hump(d.qvel)
        applied = tau
        mujoco.mj_step(m, d)
    return m, joints, np.array(log_t), np.array(log_q), np.array(log_qd), np.array(log_tau)


def degrade(req, m, joints, t, q, qd, tau):
    """What the driver publishes: quantised positions, velocity as configured, noisy effort."""
    rng = np.random.default_rng(req["seed"] + 1_000_003)
    counts = req.get("counts", 0)
    if counts:
        for j in range(len(joints)):
            step = 2 * np.pi / counts if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE else 1e-6
            q[:, j] = np.round(q[:, j] / step) * step
    velocity = req.get("velocity", "measured")
    if velocity == "encoder":
        qd = np.vstack([np.zeros((1, q.shape[1])), np.diff(q, axis=0) / np.diff(t)[:, None]])
    if velocity == "noisy":
        # A stream of its own: the effort noise is drawn as for the other velocities, and only the velocity differs.
        own = np.random.default_rng(req["seed"] + 2_000_003)
        qd = qd + own.normal(size=qd.shape) * req["velocity_noise"] * np.sqrt((qd**2).mean(axis=0))
    rms = np.sqrt((tau**2).mean(axis=0))
    noise = req.get("noise", 0.0)
    if noise:
        tau = tau + rng.normal(size=tau.shape) * noise * rms
    return q, (None if velocity == "absent" else qd), tau, rms


def write_bag(path, description, names, t, q, qd, tau, start=0, stop=None):
    with open(path, "wb") as f:
        writer = Writer(f)
        js = writer.register_msgdef("sensor_msgs/msg/JointState", JOINT_STATE)
        text = writer.register_msgdef("std_msgs/msg/String", STRING)
        t0 = 1_700_000_000_000_000_000
        if start == 0:
            writer.write_message("/robot_description", text, {"data": description}, log_time=t0, publish_time=t0)
        for i in range(start, len(t) if stop is None else stop):
            ns = t0 + int(round(t[i] * 1e9))
            msg = {
                "header": {"stamp": {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}, "frame_id": ""},
                "name": names,
                "position": [float(v) for v in q[i]],
                "velocity": [] if qd is None else [float(v) for v in qd[i]],
                "effort": [float(v) for v in tau[i]],
            }
            writer.write_message("/joint_states", js, msg, log_time=ns, publish_time=ns, sequence=i)
        writer.finish()


def perturb(req):
    """A "nominal" URDF as users have them: every link's mass, centre of mass and inertia scaled by 1 +- u with u
    drawn in [low, high] (independently per quantity, random sign), friction removed. stdin: {"urdf", "seed", "low",
    "high", "out"}; stdout: {"factors": {link: [mass, com, inertia]}}."""
    import re
    rng = np.random.default_rng(req["seed"])
    text = open(req["urdf"]).read()
    factors = {}

    def factor():
        return float(1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(req["low"], req["high"]))

    def link(m):
        body = m.group(0)
        name = re.search(r'name="([^"]+)"', body).group(1)
        f = [factor(), factor(), factor()]

        def scale(attr, k):
            return lambda a: f'{a.group(1)}="' + " ".join(repr(float(float(v) * f[k])) for v in a.group(2).split()) + '"'

        def inertial(i):
            x = i.group(0)
            x = re.sub(r'(value)="([^"]+)"', scale("value", 0), x)
            x = re.sub(r'(<origin[^>]*\sxyz)="([^"]+)"', scale("xyz", 1), x)
            x = re.sub(r'(i[xyz]{2})="([^"]+)"', scale("i", 2), x)
            return x

        factors[name] = f
        return re.sub(r"<inertial>.*?</inertial>", inertial, body, flags=re.S)

    text = re.sub(r"<link\s[^>]*>.*?</link>", link, text, flags=re.S)
    text = re.sub(r'(<dynamics[^>]*?)\sdamping="[^"]*"', r'\1 damping="0.0"', text)
    text = re.sub(r'(<dynamics[^>]*?)\sfriction="[^"]*"', r'\1 friction="0.0"', text)
    open(req["out"], "w").write(text)
    json.dump({"factors": factors}, sys.stdout)


ROBOTS = {"ur5": "ur_description/urdf/ur5_robot.urdf", "panda": "panda_description/urdf/panda.urdf"}


def main():
    if "--path" in sys.argv:
        import pathlib
        import sysconfig
        prefix = pathlib.Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix/share/example-robot-data/robots"
        print(prefix / ROBOTS[sys.argv[sys.argv.index("--path") + 1]])
        return
    if "--load" in sys.argv:
        # MuJoCo loads the URDF (as `mujoco_model` does): its degrees of freedom and total mass.
        m = mujoco_model(open(sys.argv[sys.argv.index("--load") + 1]).read())
        json.dump({"nv": int(m.nv), "mass": float(m.body_mass.sum())}, sys.stdout)
        return
    req = json.load(sys.stdin)
    if "--perturb" in sys.argv:
        perturb(req)
        return
    m, joints, t, q, qd, tau = simulate(req)
    q, qd, tau, rms = degrade(req, m, joints, t, q, qd, tau)
    description = req.get("description") or open(req["urdf"]).read()
    out = req["out"]
    if req.get("split", 1) > 1:
        os.makedirs(out, exist_ok=True)
        name = os.path.basename(os.path.normpath(out))
        cut = len(t) // 2
        write_bag(os.path.join(out, f"{name}_0.mcap"), description, joints, t, q, qd, tau, 0, cut)
        write_bag(os.path.join(out, f"{name}_1.mcap"), description, joints, t, q, qd, tau, cut, None)
    else:
        write_bag(out, description, joints, t, q, qd, tau)
    json.dump({"joints": joints, "samples": len(t), "torque_rms": list(rms)}, sys.stdout)


if __name__ == "__main__":
    main()
