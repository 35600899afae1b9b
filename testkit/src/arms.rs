//! Real arms as the tests and benchmarks of `identify` meet them: example-robot-data's UR5 and Panda, simulated by
//! MuJoCo with known friction (`tests/reference/simulate_arm.py`) and logged the way drivers write them.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

/// The MuJoCo harness that writes a real arm's log as a ROS 2 bag.
pub const HARNESS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/reference/simulate_arm.py");

/// An arm: example-robot-data's name for it, friction of the joints that move (Coulomb, viscous), joints the logs
/// hold still (to be welded by `--fix`).
pub struct Arm {
    pub name: &'static str,
    pub friction: &'static [(&'static str, f64, f64)],
    pub fixed: &'static [&'static str],
}

pub const UR5: Arm = Arm {
    name: "ur5",
    friction: &[
        ("shoulder_pan_joint", 5.0, 4.0),
        ("shoulder_lift_joint", 6.0, 5.0),
        ("elbow_joint", 4.0, 3.0),
        ("wrist_1_joint", 1.5, 1.0),
        ("wrist_2_joint", 1.2, 0.8),
        ("wrist_3_joint", 1.0, 0.5),
    ],
    fixed: &[],
};

/// Friction of the Panda's order (Gaz et al., RA-L 2019: Coulomb 0.2-0.7 N m, viscous 0.05-0.6 N m s/rad). Its
/// fingers are logged but held still: welded by `--fix` (the mimic finger by itself).
pub const PANDA: Arm = Arm {
    name: "panda",
    friction: &[
        ("panda_joint1", 0.5, 0.6),
        ("panda_joint2", 0.6, 0.6),
        ("panda_joint3", 0.4, 0.5),
        ("panda_joint4", 0.45, 0.5),
        ("panda_joint5", 0.2, 0.15),
        ("panda_joint6", 0.25, 0.15),
        ("panda_joint7", 0.2, 0.12),
    ],
    fixed: &["panda_finger_joint1"],
};

impl Arm {
    /// The friction table as the harness takes it.
    pub fn friction_json(&self) -> Value {
        let map: serde_json::Map<String, Value> =
            self.friction.iter().map(|(j, c, v)| (j.to_string(), json!([c, v]))).collect();
        Value::Object(map)
    }
}

/// What a log adds to the simulated torques.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogKind {
    Clean,
    /// 1 % effort noise, 2^17-count encoders, velocity from encoder differences.
    Noisy,
}

/// The harness run by one Python, writing into `dir`, for one arm whose true URDF is `urdf`.
pub struct Harness {
    pub python: String,
    pub dir: PathBuf,
    pub urdf: String,
}

impl Harness {
    pub fn new(python: String, dir: &Path, arm: &Arm) -> Self {
        let urdf = run(&python, &["--path", arm.name], &json!({})).trim().to_string();
        Harness { python, dir: dir.to_path_buf(), urdf }
    }

    /// Runs the harness with `args` and the request `req`; its stdout.
    pub fn run(&self, args: &[&str], req: &Value) -> String {
        run(&self.python, args, req)
    }

    /// A nominal URDF as users have them (every inertial off by 20-30 %, no friction).
    pub fn nominal(&self, seed: u64) -> PathBuf {
        let out = self.dir.join(format!("nominal{seed}.urdf"));
        self.run(&["--perturb"], &json!({"urdf": self.urdf, "seed": seed, "low": 0.2, "high": 0.3, "out": out}));
        out
    }

    /// A noisy log ([`LogKind::Noisy`], sampled effort, 1 kHz) of `arm` running the designed excitation
    /// `excitation` (an `excitation-K.json` of `dynforge excite`), its noise drawn from `seed`, written to `out`.
    pub fn excitation_log(&self, arm: &Arm, excitation: &Path, seed: u64, out: &Path) {
        self.run(&[], &json!({
            "urdf": self.urdf, "friction": arm.friction_json(), "seed": seed, "rate": 1000.0, "excitation": excitation,
            "effort": "sampled", "noise": 0.01, "counts": 131072, "velocity": "encoder", "out": out,
        }));
    }

    /// A log of `seconds` of reference motion `seed`, its effort `held` or `sampled`, at `rate` Hz; its path.
    pub fn log(&self, arm: &Arm, seed: u64, seconds: f64, effort: &str, kind: LogKind, rate: f64) -> PathBuf {
        self.log_with_drives(arm, &[], (seed, seconds), effort, kind, rate)
    }

    /// [`Harness::log`] of the arm with drives: per joint `(name, armature, offset)`, the rotor inertia MuJoCo
    /// simulates (`dof_armature`) and a constant torque added to the logged effort.
    pub fn log_with_drives(
        &self,
        arm: &Arm,
        drives: &[(&str, f64, f64)],
        (seed, seconds): (u64, f64),
        effort: &str,
        kind: LogKind,
        rate: f64,
    ) -> PathBuf {
        let tag = if drives.is_empty() { "" } else { "-drives" };
        let out = self.dir.join(format!("{}-{seed}-{effort}-{kind:?}-{rate}-{seconds}{tag}.mcap", arm.name));
        let mut req = json!({
            "urdf": self.urdf, "friction": arm.friction_json(), "seed": seed, "duration": seconds, "rate": rate,
            "effort": effort, "out": out,
        });
        if kind == LogKind::Noisy {
            req["noise"] = json!(0.01);
            req["counts"] = json!(131072);
            req["velocity"] = json!("encoder");
        }
        if !drives.is_empty() {
            let map = |f: fn(&(&str, f64, f64)) -> f64| -> Value {
                Value::Object(drives.iter().map(|d| (d.0.to_string(), json!(f(d)))).collect())
            };
            req["armature"] = map(|d| d.1);
            req["offset"] = map(|d| d.2);
        }
        self.run(&[], &req);
        out
    }
}

fn run(python: &str, args: &[&str], req: &Value) -> String {
    crate::run_python(python, Path::new(HARNESS), args, &req.to_string())
}
