//! `identify` on long logs: one hour of a 7-joint arm at 1 kHz (example-robot-data's Panda, fingers welded), written
//! as a rosbag2 directory split into several files the way a recorder splits it, with what drivers give: 1 % effort
//! noise, 2^17-count encoders, velocity from encoder differences. The torques are our inverse dynamics plus friction
//! (this measures speed; accuracy on an independent engine's logs is what `tests/real_arms.rs` checks). Timed through
//! the `dynforge identify` binary, then the reference beside it: `bench/long_log_reference.py`, Pinocchio's joint
//! torque regressor and a least-squares solve (numpy) over the same bag.
//!
//! Usage: DYNFORGE_PYTHON=.venv/bin/python dynforge-bench-long-log --dynforge target/release/dynforge
//! [--minutes 60] [--files 6] [--dir DIR] [--reference-minutes M]

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use dynforge_proto::shard::JointState;
use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, Model, friction_torque, rnea};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

const DT: f64 = 1e-3;
const COUNTS: f64 = 131_072.0;
const NOISE: f64 = 0.01;

/// Per joint a multi-sine within 35 % of its range around the middle and 60 % of its speed limit: (centre, amplitude,
/// (frequency [rad/s], phase, weight) x 5).
struct Motion {
    joints: Vec<(f64, f64, [Wave; 5])>,
}

/// (frequency [rad/s], phase, weight)
type Wave = (f64, f64, f64);

impl Motion {
    fn new(model: &Model, rng: &mut Rng) -> Self {
        let joints = model
            .joints()
            .iter()
            .map(|j| {
                let (lo, hi) = (j.limits.lower.max(-std::f64::consts::PI), j.limits.upper.min(std::f64::consts::PI));
                let waves: [Wave; 5] = std::array::from_fn(|_| {
                    (
                        std::f64::consts::TAU * rng.uniform(0.1, 0.8),
                        rng.uniform(0.0, std::f64::consts::TAU),
                        rng.uniform(0.5, 1.0),
                    )
                });
                let weight: f64 = waves.iter().map(|w| w.2).sum();
                let mut amp = 0.35 * 0.5 * (hi - lo) / weight;
                let speed = amp * waves.iter().map(|w| w.2 * w.0).sum::<f64>();
                if speed > 0.6 * j.limits.velocity {
                    amp *= 0.6 * j.limits.velocity / speed;
                }
                (0.5 * (lo + hi), amp, waves)
            })
            .collect();
        Motion { joints }
    }

    /// Position, velocity and acceleration of every joint at `t`.
    fn at(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        for (j, (centre, amp, waves)) in self.joints.iter().enumerate() {
            let (mut x, mut dx, mut ddx) = (0.0, 0.0, 0.0);
            for &(w, p, a) in waves {
                let (s, c) = (w * t + p).sin_cos();
                (x, dx, ddx) = (x + a * s, dx + a * w * c, ddx - a * w * w * s);
            }
            (q[j], qd[j], qdd[j]) = (centre + amp * x, amp * dx, amp * ddx);
        }
    }
}

/// Writes `minutes` of the arm's log as `files` MCAP files `dir/long_K.mcap`; returns the samples written.
fn write_log(model: &Model, urdf: &str, dir: &Path, minutes: f64, files: usize) -> Result<usize> {
    let n = model.dof();
    let samples = (minutes * 60.0 / DT).round() as usize;
    let mut rng = Rng::stream(1, &[]);
    let motion = Motion::new(model, &mut rng);
    let (mut q, mut qd, mut qdd, mut fr) = (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    let mut data = Data::new(model);
    // Each joint's torque scale for the noise: its RMS over the first minute.
    let mut rms = vec![0.0; n];
    for i in 0..60_000 {
        motion.at(i as f64 * DT, &mut q, &mut qd, &mut qdd);
        let tau = rnea(model, &mut data, &q, &qd, &qdd);
        rms.iter_mut().zip(tau.iter()).for_each(|(r, t)| *r += t * t / 60_000.0);
    }
    rms.iter_mut().for_each(|r| *r = r.sqrt());
    let names: std::sync::Arc<[String]> = model.joints().iter().map(|j| j.name.clone()).collect();
    let quantum = std::f64::consts::TAU / COUNTS;
    let per_file = samples.div_ceil(files);
    let mut last = vec![f64::NAN; n];
    for f in 0..files {
        let range = f * per_file..((f + 1) * per_file).min(samples);
        let mut messages = Vec::with_capacity(range.len());
        for i in range {
            let t = i as f64 * DT;
            motion.at(t, &mut q, &mut qd, &mut qdd);
            friction_torque(model, &qd, &mut fr);
            let tau = rnea(model, &mut data, &q, &qd, &qdd);
            let position: Vec<f64> = q.iter().map(|x| (x / quantum).round() * quantum).collect();
            let velocity: Vec<f64> =
                position.iter().zip(&last).map(|(p, l)| if l.is_nan() { 0.0 } else { (p - l) / DT }).collect();
            last.copy_from_slice(&position);
            let effort = (0..n).map(|j| tau[j] + fr[j] + NOISE * rms[j] * rng.normal()).collect();
            let ns = (i as u64) * 1_000_000;
            messages.push(JointState {
                sec: (ns / 1_000_000_000) as i32,
                nanosec: (ns % 1_000_000_000) as u32,
                frame_id: String::new(),
                name: names.clone(),
                position,
                velocity,
                effort,
            });
        }
        let content = dynforge_shard::ShardContent { urdf, joint_states: &messages, metadata: &Default::default() };
        dynforge_shard::write(&dir.join(format!("long_{f}.mcap")), &content)?;
    }
    Ok(samples)
}

/// Peak resident memory of the children waited for so far [MB].
fn children_peak_mb() -> f64 {
    // SAFETY: getrusage only writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    usage.ru_maxrss as f64 / 1024.0
}

const USAGE: &str = "usage: dynforge-bench-long-log --dynforge RELEASE_BINARY [--minutes 60] [--files 6] [--dir DIR] \
                     [--reference-minutes M]\n\
Synthesizes an hour-long 1 kHz Panda log (1 % effort noise, 2^17-count encoders, velocity differenced), times \
`dynforge identify` on it and a Pinocchio + numpy least-squares reference on the same log, the first M minutes of \
it with --reference-minutes M (0: no reference; it takes ~3 minutes for the hour) (DYNFORGE_PYTHON: the venv of \
scripts/venv.sh); prints both per sample, side by side.";

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut minutes, mut files, mut dir, mut dynforge, mut reference) = (60.0, 6, None, None, None);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--minutes" => minutes = value()?.parse()?,
            "--files" => files = value()?.parse()?,
            "--dir" => dir = Some(PathBuf::from(value()?)),
            "--dynforge" => dynforge = Some(PathBuf::from(value()?)),
            "--reference-minutes" => reference = Some(value()?.parse::<f64>()?),
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            _ => bail!("unknown option {a}\n\n{USAGE}"),
        }
    }
    let dynforge = dynforge.context("--dynforge PATH: the release binary to time")?;
    let py = std::env::var("DYNFORGE_PYTHON").context("DYNFORGE_PYTHON: the venv of scripts/venv.sh")?;
    let harness =
        dynforge_testkit::arms::Harness::new(py.clone(), &std::env::temp_dir(), &dynforge_testkit::arms::PANDA);
    let urdf = std::fs::read_to_string(&harness.urdf).with_context(|| harness.urdf.clone())?;
    let welds = ["panda_finger_joint1", "panda_finger_joint2"].map(|j| (j.to_string(), 0.0)).into_iter().collect();
    let model = dynforge_robot::urdf::parse_welded(&urdf, &harness.urdf, &welds)?;
    let dir = dir.unwrap_or_else(|| std::env::temp_dir().join("dynforge-long-log"));
    let bag = dir.join("long");
    std::fs::create_dir_all(&bag)?;
    let start = Instant::now();
    let samples = write_log(&model, &urdf, &bag, minutes, files)?;
    eprintln!(
        "wrote {samples} samples of {} joints in {files} files in {:.1} s",
        model.dof(),
        start.elapsed().as_secs_f64()
    );

    let start = Instant::now();
    let out = std::process::Command::new(&dynforge)
        .arg("identify")
        .arg(&bag)
        .args(["--effort", "sampled", "--out"])
        .arg(dir.join("long.calibrated.urdf"))
        .output()?;
    let seconds = start.elapsed().as_secs_f64();
    if !out.status.success() {
        bail!("identify failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    let peak = children_peak_mb();
    println!(
        "{}",
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter(|l| l.contains("NRMSE") || l.contains("samples"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    println!(
        "identify: {minutes} min of 1 kHz x {} joints in {seconds:.2} s wall ({:.2} us per sample), peak RSS {peak:.0} MB",
        model.dof(),
        1e6 * seconds / samples as f64
    );

    if reference == Some(0.0) {
        return Ok(());
    }
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/long_log_reference.py");
    let mut cmd = std::process::Command::new(&py);
    cmd.arg(script).arg(&bag).arg(&harness.urdf);
    if let Some(m) = reference {
        cmd.args(["--minutes", &m.to_string()]);
    }
    let out = cmd.output()?;
    if !out.status.success() {
        bail!("the reference failed: {}", String::from_utf8_lossy(&out.stderr));
    }
    print!("{}", String::from_utf8_lossy(&out.stdout));
    Ok(())
}
