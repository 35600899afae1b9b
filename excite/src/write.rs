//! The design written as a user runs it: per trajectory a CSV of time, positions, velocities and accelerations at the
//! controller's rate, the same as a JointTrajectory message in MCAP (what `ros2 bag play` sends a
//! joint_trajectory_controller) and the series' coefficients as JSON (exact, to regenerate any rate), and a report.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use dynforge_proto::family::{ExcitationSet, SET, excitation_file};
use dynforge_proto::fourier::Excitation;
use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_proto::shard::TrajectoryPoint;
use dynforge_robot::Model;

use crate::baseline::DRAWS;
use crate::design::LOOSER;
use crate::information::{Quality, expected_std};
use crate::motion::{BAND, SINES};
use crate::{Design, ExciteError, Options};

const INERTIAL_NAMES: [&str; NI] = ["mass", "mx", "my", "mz", "ixx", "ixy", "iyy", "ixz", "iyz", "izz"];

/// Written whole or not at all (the run directories' rule): a rerun interrupted midway leaves the previous files.
fn write(path: &Path, text: &str) -> Result<(), ExciteError> {
    dynforge_proto::run_dir::write_atomic(path, text.as_bytes())
        .map_err(|source| ExciteError::Write { file: path.display().to_string(), source })
}

/// Writes `excitation-K.csv`, `excitation-K.mcap` (a `trajectory_msgs/msg/JointTrajectory`) and `excitation-K.json`
/// per trajectory, `report.md` and last the set's manifest (`dynforge_proto::family::SET`) into `dir` (created);
/// returns the files written. The directory is one unit: the manifest goes first, so an interrupted write leaves a
/// set no reader takes as complete, and members of an earlier, larger set are removed. `rate` is the CSV's [Hz];
/// the expected deviations assume `options.noise`.
pub fn write_design(
    dir: &Path,
    model: &Model,
    design: &Design,
    options: &Options,
    rate: f64,
) -> Result<Vec<PathBuf>, ExciteError> {
    let failed = |path: &Path| {
        let file = path.display().to_string();
        move |source| ExciteError::Write { file, source }
    };
    std::fs::create_dir_all(dir).map_err(failed(dir))?;
    let manifest = dir.join(SET);
    match std::fs::remove_file(&manifest) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(failed(&manifest)(e)),
        _ => {}
    }
    let n = model.dof();
    let mut texts = Vec::new();
    let names: Vec<&str> = model.joints().iter().map(|j| j.name.as_str()).collect();
    let mut files = Vec::new();
    for (k, f) in design.trajectories.iter().enumerate() {
        let mut points = Vec::new();
        let mut csv = String::from("t");
        for what in ["q", "qd", "qdd"] {
            for name in &names {
                let _ = write!(csv, ",{what}_{name}");
            }
        }
        csv.push('\n');
        let samples = (f.period * rate).round() as usize;
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for i in 0..=samples {
            let t = i as f64 / rate;
            f.at(t, &mut q, &mut qd, &mut qdd);
            let _ = write!(csv, "{t:.6}");
            for v in q.iter().chain(&qd).chain(&qdd) {
                let _ = write!(csv, ",{v:.9}");
            }
            csv.push('\n');
            points.push(TrajectoryPoint {
                positions: q.clone(),
                velocities: qd.clone(),
                accelerations: qdd.clone(),
                time_from_start_ns: (i as f64 * 1e9 / rate).round() as u64,
            });
        }
        let path = dir.join(format!("excitation-{k}.mcap"));
        let joint_names: Vec<String> = names.iter().map(|s| s.to_string()).collect();
        dynforge_shard::write_joint_trajectory(&path, &joint_names, &points)?;
        files.push(path);
        let path = dir.join(format!("excitation-{k}.csv"));
        write(&path, &csv)?;
        files.push(path);
        let excitation = Excitation { joints: joint_names, series: f.clone() };
        let json = serde_json::to_string_pretty(&excitation).expect("an excitation serialises");
        let path = dir.join(excitation_file(k));
        let text = format!("{json}\n");
        write(&path, &text)?;
        files.push(path);
        texts.push(text);
    }
    for stale in stale_members(dir, design.trajectories.len()).map_err(failed(dir))? {
        std::fs::remove_file(&stale).map_err(failed(&stale))?;
    }
    let path = dir.join("report.md");
    write(&path, &report(model, design, options))?;
    files.push(path);
    let set = serde_json::to_string_pretty(&ExcitationSet::of(&texts)).expect("a manifest serialises");
    write(&manifest, &format!("{set}\n"))?;
    files.push(manifest);
    Ok(files)
}

/// The files of `dir` named as members past the first `count` (`excitation-K.csv`, `.mcap`, `.json`, K >= count):
/// what an earlier run with a larger `--count` left.
fn stale_members(dir: &Path, count: usize) -> std::io::Result<Vec<PathBuf>> {
    let mut stale = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let name = entry?.file_name();
        let Some(name) = name.to_str() else { continue };
        let member = name.strip_prefix("excitation-").and_then(|rest| rest.split_once('.'));
        if let Some((k, "csv" | "mcap" | "json")) = member
            && k.parse::<usize>().is_ok_and(|k| k >= count)
        {
            stale.push(dir.join(name));
        }
    }
    stale.sort();
    Ok(stale)
}

/// The quality table: the design together and each trajectory alone, beside the random multi-sines (best and
/// median of their draws), the generator's tours and the design at a looser acceleration limit; then the gains.
fn quality_table(out: &mut String, design: &Design, options: &Options) {
    let count = options.count;
    let _ = writeln!(out, "| | mean log eigenvalue | condition number | covariance trace |");
    let _ = writeln!(out, "|---|---:|---:|---:|");
    let mut row = |name: &str, q: &Quality| {
        let _ = writeln!(out, "| {name} | {:.3} | {:.3e} | {:.3e} |", q.log_det, q.condition, q.trace);
    };
    row("designed, together", &design.together);
    if let Some(m) = &design.multisines {
        row(&format!("random multi-sines, sets of {count}: best of {DRAWS}"), &m.sets.best);
        row(&format!("random multi-sines, sets of {count}: median of {DRAWS}"), &m.sets.median);
    }
    if let Some(t) = &design.tours {
        row("the dataset generator's waypoint tours, same total time", t);
    }
    row(&format!("designed, searched again at {LOOSER}x the acceleration limit"), &design.looser);
    for (k, q) in design.alone.iter().enumerate() {
        row(&format!("trajectory {k} alone"), q);
    }
    if let Some(m) = &design.multisines {
        row(&format!("one random multi-sine: best of {DRAWS}"), &m.alone.best);
        row(&format!("one random multi-sine: median of {DRAWS}"), &m.alone.median);
    }
    let _ = writeln!(
        out,
        "\nThe random multi-sines are the usual excitation without a design: per joint {SINES} sines with frequencies \
         drawn in {}-{} Hz, random phases and amplitudes 1/omega, faded in and out so they start and end at rest at \
         the same pose; each joint scaled alone until it reaches 95 % of the speed bound, 96 % of its position room \
         or the acceleration limit, whichever comes first; then all together until the effort fits. Self-collision is \
         not checked for them (the design is checked). Best and median are per column.\n",
        BAND.0, BAND.1
    );
    if let Some(line) = against_multisines(design) {
        let m = design.multisines.expect("a sentence only with multi-sines");
        let worst = design
            .alone
            .iter()
            .map(|q| gain(q, &m.alone.best))
            .fold((f64::INFINITY, f64::INFINITY), |a, b| (a.0.min(b.0), a.1.min(b.1)));
        let _ = writeln!(
            out,
            "The design together: {line}. Each trajectory alone against the best single multi-sine: at least {:.1}x \
             smaller covariance trace and {:.2}x the information per dimension.\n",
            worst.0, worst.1
        );
    }
    if let Some(t) = &design.tours {
        let _ = writeln!(
            out,
            "Against the generator's waypoint tours (16-waypoint protocol: minimum-jerk moves at half the speed limit, \
             each held 2 s): base covariance trace {:.1}x smaller.\n",
            t.trace / design.together.trace
        );
    }
    let accelerations: Vec<String> = options.acceleration.iter().map(|a| format!("{a}")).collect();
    let _ = writeln!(
        out,
        "What the acceleration limit ({} rad/s^2) costs: the design searched again from where it is at {LOOSER}x the \
         limit (a tenth of the evaluations, the other bounds and self-collision as before) reaches a base covariance \
         trace {:.2}x smaller and {:.2}x the information per dimension.\n",
        accelerations.join(", "),
        design.together.trace / design.looser.trace,
        (design.looser.log_det - design.together.log_det).exp()
    );
}

/// What a check of no body pair says (never "free of self-collision").
const NO_PAIR: &str = "self-collision: no pair of bodies to check (each pair is joined by one joint, touches at the \
                       start pose, or has no collision geometry)";

/// How many times smaller a covariance trace than `base`'s, and how many times larger the information per dimension
/// (the geometric mean of its eigenvalues, `det^(1/rank)`).
fn gain(design: &Quality, base: &Quality) -> (f64, f64) {
    (base.trace / design.trace, (design.log_det - base.log_det).exp())
}

/// The design's gain over the best and the median random multi-sine set, as one sentence's middle.
fn against_multisines(design: &Design) -> Option<String> {
    let m = design.multisines?;
    let (best, median) = (gain(&design.together, &m.sets.best), gain(&design.together, &m.sets.median));
    Some(format!(
        "base covariance trace {:.1}x smaller than the best of {DRAWS} random sets of multi-sines within the same limits ({:.1}x the median), information per dimension {:.2}x larger ({:.2}x)",
        best.0, median.0, best.1, median.1
    ))
}

/// A few lines for the terminal: what was designed and what it is worth beside random multi-sines, the generator's
/// tours and a looser acceleration limit.
pub fn summary(model: &Model, design: &Design, options: &Options) -> String {
    let collision = match &design.clearance {
        Some(c) if c.pairs == 0 => NO_PAIR.to_string() + "\n",
        Some(c) => {
            let pairs = c.pairs;
            let (closest, pair) = c
                .closest
                .iter()
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .map_or((f64::INFINITY, ""), |(d, p)| (*d, p.as_str()));
            format!("free of self-collision ({pairs} body pairs checked; closest {:.1} mm: {pair})\n", 1e3 * closest)
        }
        None => "self-collision not checked\n".to_string(),
    };
    let mut out = collision
        + &format!(
            "{} trajectories of {} s for {} ({} of {} parameter combinations identifiable), condition number {:.3e}\n",
            options.count,
            options.duration,
            model.name(),
            design.base.rank(),
            design.scales.len(),
            design.together.condition,
        );
    if let Some(line) = against_multisines(design) {
        out += &line;
        out += "\n";
    }
    if let Some(t) = &design.tours {
        out += &format!(
            "base covariance trace {:.1}x smaller than the dataset generator's waypoint tours'\n",
            t.trace / design.together.trace
        );
    }
    out += &format!(
        "at {LOOSER}x the acceleration limit the design would reach a base covariance trace {:.2}x smaller\n",
        design.together.trace / design.looser.trace
    );
    out
}

/// The report: how the design was asked for, its quality beside what it is measured against, the peaks it reaches,
/// and per parameter the standard deviation least squares would give at the torque noise of `options`.
pub fn report(model: &Model, design: &Design, options: &Options) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# Excitation of {}\n", model.name());
    let _ = writeln!(
        out,
        "{} trajectories of {} s, {} harmonics ({:.2} Hz at most), starting and ending at rest at {:?}.\n",
        options.count,
        options.duration,
        options.harmonics,
        options.harmonics as f64 / options.duration,
        design.trajectories[0].start
    );
    let _ = writeln!(
        out,
        "{} of {} parameter combinations are identifiable from torques (the base parameters).\n",
        design.base.rank(),
        design.scales.len()
    );
    quality_table(&mut out, design, options);
    let _ = writeln!(
        out,
        "Peaks reached, as shares of the limits (position range less margin, velocity, acceleration, effort):\n"
    );
    for (k, p) in design.peaks.iter().enumerate() {
        let _ = writeln!(out, "- trajectory {k}: {:.2} / {:.2} / {:.2} / {:.2}", p[0], p[1], p[2], p[3]);
    }
    match &design.clearance {
        Some(c) if c.pairs == 0 => {
            let _ = writeln!(out, "\nSelf-collision: {}.", NO_PAIR.trim_start_matches("self-collision: "));
        }
        Some(c) => {
            let (per_trajectory, pairs, padding) = (&c.closest, c.pairs, c.padding);
            let _ = writeln!(
                out,
                "\nSelf-collision: checked with the URDF's collision geometry (meshes as their convex hulls, which only \
                 add volume) at 1 kHz, {pairs} pairs of bodies kept at least {:.1} mm apart (bodies joined by one \
                 joint, and bodies that touch at the start pose, are not checked). Smallest distance between checked \
                 bodies:\n",
                1e3 * padding
            );
            for (k, (d, pair)) in per_trajectory.iter().enumerate() {
                let _ = writeln!(out, "- trajectory {k}: {:.1} mm ({pair})", 1e3 * d);
            }
            let _ = writeln!(
                out,
                "\nNot checked: the robot's surroundings (table, floor, fixtures). Run each trajectory slowly before \
                 at speed."
            );
        }
        None => {
            let _ = writeln!(
                out,
                "\nNot checked: collisions of the arm with itself or its surroundings. Run each trajectory in a \
                 simulator or slowly on the robot before running it at speed.\n"
            );
        }
    }
    let std = expected_std(&design.base, &design.information, &design.scales);
    let noise: Vec<String> = options.noise.iter().map(|s| format!("{s}")).collect();
    let _ = writeln!(
        out,
        "\nExpected standard deviation of each parameter's identifiable part by least squares, with white torque noise \
         of {} N m (N for a prismatic joint) {} sampled at {} Hz (parameters about each link's joint frame; 0 = the \
         torques see nothing of it; the design weighs each joint's torques by the inverse of its noise):\n",
        noise.join(", "),
        if noise.len() == 1 { "on every joint" } else { "per joint" },
        options.rate
    );
    let _ = writeln!(out, "| link | {} |", INERTIAL_NAMES.join(" | "));
    let _ = writeln!(out, "|---|{}", "---:|".repeat(NI));
    for (l, link) in model.links().iter().enumerate() {
        let cells: Vec<String> = (0..NI).map(|k| format!("{:.2e}", std[NI * l + k])).collect();
        let _ = writeln!(out, "| {} | {} |", link.name, cells.join(" | "));
    }
    let _ = writeln!(out, "\n| joint | coulomb | viscous |\n|---|---:|---:|");
    let n = model.dof();
    for (j, joint) in model.joints().iter().enumerate() {
        let at = NI * n + NF * j;
        let _ = writeln!(out, "| {} | {:.2e} | {:.2e} |", joint.name, std[at], std[at + 1]);
    }
    out
}
