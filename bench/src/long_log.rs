//! `identify` on long logs: one hour of a 7-joint arm at 1 kHz (example-robot-data's Panda, fingers welded), written
//! as a rosbag2 directory split into several files the way a recorder splits it, with what drivers give: 1 % effort
//! noise, 2^17-count encoders, velocity from encoder differences. The torques are our inverse dynamics plus friction
//! (this measures speed; accuracy on an independent engine's logs is what `tests/real_arms.rs` checks). Timed through
//! the `dynforge identify` binary, then the reference beside it: `bench/long_log_reference.py`, Pinocchio's joint
//! torque regressor and a least-squares solve (numpy) over the same bag.
//!
//! The same messages are also written as a ROS 2 Humble bag (rosbag2's sqlite3 storage, split alike) and as one CSV
//! table with its column map, and `identify` is timed on each, its peak memory measured child by child: what reading
//! a Humble bag or a table costs beside MCAP.
//!
//! Usage: DYNFORGE_PYTHON=.venv/bin/python dynforge-bench-long-log --dynforge target/release/dynforge
//! [--minutes 60] [--files 6] [--dir DIR] [--reference-minutes M] [--formats mcap,db3,csv]

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
/// The log's forms written, and where: an MCAP rosbag2 directory always, a sqlite3 one and a table when asked.
struct Forms<'a> {
    mcap: &'a Path,
    db3: Option<&'a Path>,
    csv: Option<&'a Path>,
}

fn write_log(model: &Model, urdf: &str, forms: &Forms, minutes: f64, files: usize) -> Result<usize> {
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
    let mut csv = match forms.csv {
        Some(path) => {
            write_column_map(model, &path.with_extension("columns.toml"))?;
            let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
            csv_header(&mut w, model)?;
            Some(w)
        }
        None => None,
    };
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
        dynforge_shard::write(&forms.mcap.join(format!("long_{f}.mcap")), &content)?;
        if let Some(dir) = forms.db3 {
            dynforge_recording::sqlite::write(&dir.join(format!("long_{f}.db3")), Some(urdf), &messages)?;
        }
        if let Some(csv) = &mut csv {
            write_rows(csv, &messages)?;
        }
    }
    if let Some(csv) = csv {
        csv.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    }
    Ok(samples)
}

/// The table's header: `t`, then per joint `NAME.q`, `NAME.qd`, `NAME.effort`.
fn csv_header(w: &mut impl std::io::Write, model: &Model) -> Result<()> {
    write!(w, "t")?;
    for j in model.joints() {
        write!(w, ",{0}.q,{0}.qd,{0}.effort", j.name)?;
    }
    writeln!(w)?;
    Ok(())
}

/// `messages` as rows of the table (Rust's shortest round-trip decimal: the same doubles read back).
fn write_rows(w: &mut impl std::io::Write, messages: &[JointState]) -> Result<()> {
    for m in messages {
        write!(w, "{}", m.stamp_ns() as f64 * 1e-9)?;
        for j in 0..m.name.len() {
            write!(w, ",{},{},{}", m.position[j], m.velocity[j], m.effort[j])?;
        }
        writeln!(w)?;
    }
    Ok(())
}

/// The column map of the table [`write_rows`] writes, by header name.
fn write_column_map(model: &Model, path: &Path) -> Result<()> {
    let mut text = String::from("header = true\ntime = { column = \"t\" }\n");
    for j in model.joints() {
        let n = &j.name;
        text += &format!("[joints.{n}]\nposition = \"{n}.q\"\nvelocity = \"{n}.qd\"\neffort = \"{n}.effort\"\n");
    }
    std::fs::write(path, text)?;
    Ok(())
}

/// Runs `cmd` to its end: its stdout, wall seconds and peak resident memory [MB] (its own, from wait4).
fn run_measured(cmd: &mut std::process::Command) -> Result<(String, f64, f64)> {
    use std::io::Read;
    let start = Instant::now();
    let mut child = cmd.stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn()?;
    let (mut out, mut err) = (child.stdout.take().context("stdout")?, child.stderr.take().context("stderr")?);
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = err.read_to_string(&mut text);
        text
    });
    let mut stdout = String::new();
    out.read_to_string(&mut stdout)?;
    let (mut status, mut usage): (libc::c_int, libc::rusage) = (0, unsafe { std::mem::zeroed() });
    // SAFETY: wait4 writes only the status and the struct it is given, for a child of ours not yet waited for.
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    let seconds = start.elapsed().as_secs_f64();
    let stderr = reader.join().unwrap_or_default();
    if pid < 0 || !libc::WIFEXITED(status) || libc::WEXITSTATUS(status) != 0 {
        bail!("{cmd:?} failed: {stderr}");
    }
    Ok((stdout, seconds, usage.ru_maxrss as f64 / 1024.0))
}

const USAGE: &str = "usage: dynforge-bench-long-log --dynforge RELEASE_BINARY [--minutes 60] [--files 6] [--dir DIR] \
                     [--reference-minutes M] [--formats mcap,db3,csv]\n\
Synthesizes an hour-long 1 kHz Panda log (1 % effort noise, 2^17-count encoders, velocity differenced), times \
`dynforge identify` on it (as MCAP, and as a sqlite3 bag and a CSV table when --formats names them) and a Pinocchio + numpy least-squares reference on the same log, the first M minutes of \
it with --reference-minutes M (0: no reference; it takes ~3 minutes for the hour) (DYNFORGE_PYTHON: the venv of \
scripts/venv.sh); prints both per sample, side by side.";

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut minutes, mut files, mut dir, mut dynforge, mut reference) = (60.0, 6, None, None, None);
    let mut formats = vec!["mcap".to_string(), "db3".into(), "csv".into()];
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--minutes" => minutes = value()?.parse()?,
            "--files" => files = value()?.parse()?,
            "--dir" => dir = Some(PathBuf::from(value()?)),
            "--dynforge" => dynforge = Some(PathBuf::from(value()?)),
            "--reference-minutes" => reference = Some(value()?.parse::<f64>()?),
            "--formats" => formats = value()?.split(',').map(str::to_string).collect(),
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
    let (db3, csv) = (dir.join("long-db3"), dir.join("long.csv"));
    std::fs::create_dir_all(&bag)?;
    std::fs::create_dir_all(&db3)?;
    let wants = |f: &str| formats.iter().any(|x| x == f);
    let forms =
        Forms { mcap: &bag, db3: wants("db3").then_some(db3.as_path()), csv: wants("csv").then_some(csv.as_path()) };
    let start = Instant::now();
    let samples = write_log(&model, &urdf, &forms, minutes, files)?;
    eprintln!(
        "wrote {samples} samples of {} joints in {files} files in {:.1} s",
        model.dof(),
        start.elapsed().as_secs_f64()
    );

    let columns = csv.with_extension("columns.toml");
    let runs: Vec<(&str, &Path, Vec<&str>)> = [
        ("mcap", bag.as_path(), vec![]),
        ("db3", db3.as_path(), vec![]),
        ("csv", csv.as_path(), vec!["--columns", columns.to_str().context("a UTF-8 path")?]),
    ]
    .into_iter()
    .filter(|(f, _, _)| wants(f))
    .collect();
    let mut first: Option<(f64, f64, Vec<u8>)> = None;
    for (form, log, extra) in runs {
        let out_urdf = dir.join(format!("long-{form}.calibrated.urdf"));
        let mut cmd = std::process::Command::new(&dynforge);
        cmd.arg("identify").arg(log).args(["--urdf", &harness.urdf, "--effort", "sampled", "--out"]);
        cmd.arg(&out_urdf).args(extra);
        let (stdout, seconds, peak) = run_measured(&mut cmd)?;
        let lines: Vec<&str> = stdout.lines().filter(|l| l.contains("NRMSE") || l.contains("samples")).collect();
        println!("{}", lines.join("\n"));
        let written = std::fs::read(&out_urdf)?;
        let versus = match &first {
            Some((s, p, urdf)) => format!(
                " ({:.2}x the time, {:.2}x the memory of MCAP; URDF {})",
                seconds / s,
                peak / p,
                if *urdf == written { "byte-identical" } else { "DIFFERENT" }
            ),
            None => String::new(),
        };
        println!(
            "identify {form}: {minutes} min of 1 kHz x {} joints in {seconds:.2} s wall ({:.2} us per sample), peak RSS \
             {peak:.0} MB{versus}",
            model.dof(),
            1e6 * seconds / samples as f64
        );
        first.get_or_insert((seconds, peak, written));
    }

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
