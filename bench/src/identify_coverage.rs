//! Whether the spreads `identify` reports are standard deviations, on real arms: example-robot-data's UR5 and Panda
//! logged by MuJoCo (`tests/reference/simulate_arm.py`), calibrated from nominal URDFs drawn from the prior the
//! calibration assumes (each link's log-Cholesky coordinates around the true ones with the `--spread` it is given,
//! no friction), so that the truth lies where the prior says. Each parameter's `z = (value - truth) / std` should
//! fall within 1 about 68 % of the time and within 2 about 95 %, per kind, clean and noisy (1 % effort noise, 2^17
//! encoders, velocity from encoder differences). Each nominal has a log of its own (another multi-sine, another
//! noise draw), so that the parameters the torques decide are as many draws as the nominals.
//!
//! Usage: DYNFORGE_PYTHON=.venv/bin/python dynforge-bench-identify-coverage [--nominals N] [--seconds S]
//! [--spread X] [--arm ur5|panda] [--dump FILE]
//!
//! Or on a robot's family (`generate --urdf`, simulated by dynforge's own engine, noise-free): each variant
//! identified from the family's URDF with the family's spread, from its first log and from all its logs, against the
//! truth its shard carries: `dynforge-bench-identify-coverage --family DIR [--robots N] [--fix JOINT ...]
//! [--noise X] [--dump FILE]`. `--noise X` degrades every variant's logs as a bag's (white effort noise of X times
//! each joint's torque RMS, a 2^17 counts/rev encoder, the velocity from the positions); `--dump` writes every
//! parameter's z, value, truth and spreads, a line each.

use std::collections::BTreeMap;

use anyhow::{Context, Result, bail};
use dynforge_identify::calibrate::family::Degradation;
use dynforge_identify::calibrate::identify_read;
use dynforge_identify::calibrate::{Decided, Identification, Options, identify_logs};
use dynforge_identify::signals::{Conditioning, EffortConvention, VelocitySource};
use dynforge_proto::spread::Spread;
use dynforge_recording::Reading;
use dynforge_recording::dataset::shards_by_robot;
use dynforge_recording::log::{Log, read_log, read_logs};
use dynforge_robot::prior::CoordinatePrior;
use dynforge_robot::rng::Rng;
use dynforge_robot::spatial::log_cholesky::COORDINATES;
use dynforge_testkit::arms::{Arm, Harness, LogKind, PANDA, UR5};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// |z| per (kind, what decided it).
type Zs = BTreeMap<(&'static str, &'static str), Vec<f64>>;

fn add(zs: &mut Zs, id: &Identification, truth: &Identification) {
    for (p, t) in id.parameters().into_iter().zip(truth.parameters()) {
        let (kind, e) = (p.kind.name(), p.estimate);
        let decided = if e.decided == Decided::Torques { "torques" } else { "prior" };
        let z = e.z(t.estimate.value).abs();
        for key in [(kind, decided), (kind, "all"), ("all", decided), ("all", "all")] {
            zs.entry(key).or_default().push(z);
        }
    }
}

fn print(case: &str, zs: &mut Zs) {
    for ((kind, decided), v) in zs.iter_mut() {
        v.sort_by(f64::total_cmp);
        let within = |c: f64| 100.0 * v.iter().filter(|&&z| z < c).count() as f64 / v.len() as f64;
        let median = v[v.len() / 2];
        println!(
            "| {case} | {kind} | {decided} | {} | {:.0} % | {:.0} % | {median:.2} |",
            v.len(),
            within(1.0),
            within(2.0)
        );
    }
}

fn arm_coverage(
    py: &str,
    dir: &std::path::Path,
    arm: &Arm,
    (nominals, seconds, spread): (u64, f64, Spread),
    dump: &mut Dump,
) -> Result<()> {
    let harness = Harness::new(py.to_string(), dir, arm);
    let truth_text = std::fs::read_to_string(&harness.urdf).with_context(|| harness.urdf.clone())?;
    let fixed: Vec<String> = arm.fixed.iter().map(|s| s.to_string()).collect();
    for kind in [LogKind::Clean, LogKind::Noisy] {
        // A log of its own per nominal (another motion, another noise draw): with one log for all, the parameters
        // the torques decide would err alike on every nominal, one draw counted thirty times.
        let logs: Vec<_> = (0..nominals).map(|i| harness.log(arm, 1 + i, seconds, "held", kind, 1000.0)).collect();
        let first = logs.first().context("--nominals: at least one")?;
        let truth = read_log(first, Some((&truth_text, "true.urdf")), &Reading::welding(&fixed))?;
        let prior = CoordinatePrior::of(&truth.model, spread)?;
        let options = Options {
            spread,
            conditioning: Conditioning { effort: Some(EffortConvention::Held), ..Conditioning::default() },
            reading: Reading::welding(&fixed),
            weld_idle: true,
            ..Options::default()
        };
        let mut zs = Zs::new();
        let mut failed = 0;
        for (i, log) in (0..nominals).zip(&logs) {
            let mut rng = Rng::stream(7, &[i]);
            let nominal = prior.draw(&truth.model, || rng.normal())?;
            let text = truth.urdf_of(&nominal)?;
            match identify_logs(std::slice::from_ref(log), Some((&text, "nominal.urdf")), &options) {
                Ok((id, _)) => {
                    let mut at_truth = id.clone();
                    at_truth.report_values_of(&truth.model);
                    // The true friction is the harness's (MuJoCo's joints), not the URDF's.
                    for j in &mut at_truth.joints {
                        let (_, c, v) = arm.friction.iter().find(|f| f.0 == j.name).context("a moving joint")?;
                        (j.coulomb.value, j.viscous.value) = (*c, *v);
                    }
                    add(&mut zs, &id, &at_truth);
                    if let Some(out) = dump.as_mut() {
                        let calibrated = CoordinatePrior::of(&id.model, spread)?;
                        let [truth, map] = prior_distances(&nominal, spread, [&prior, &calibrated])?;
                        write_dump(out, &format!("{} {kind:?}", arm.name), i, (&id, &at_truth), Some((&truth, &map)))?;
                    }
                }
                Err(e) => {
                    failed += 1;
                    eprintln!("{} {kind:?} nominal {i}: {e}", arm.name);
                }
            }
        }
        eprintln!("{} {kind:?}: {nominals} nominals, {failed} refused", arm.name);
        print(&format!("{} {kind:?}", arm.name), &mut zs);
    }
    Ok(())
}

/// The degradation of a bag of the robot `logs` show: white effort noise of `noise` times each joint's torque RMS,
/// positions on a 2^17 counts/rev encoder's grid, the effort held (the family's).
fn bag_like(logs: &[Log], noise: f64) -> Degradation {
    let n = logs[0].model.dof();
    let (mut sum, mut count) = (vec![0.0; n], 0usize);
    for seg in logs.iter().flat_map(|l| &l.segments) {
        for row in seg.tau.chunks(n) {
            for (s, t) in sum.iter_mut().zip(row) {
                *s += t * t;
            }
            count += 1;
        }
    }
    Degradation {
        effort: EffortConvention::Held,
        effort_noise: sum.iter().map(|s| noise * (s / count.max(1) as f64).sqrt()).collect(),
        encoder_step: vec![Some(std::f64::consts::TAU / f64::from(1u32 << 17)); n],
    }
}

/// Per link (by name), a point's squared whitened distance under the prior the calibration was given: for the truth,
/// a chi-square with 10 degrees of freedom where the truth is what that prior says it might be; for the calibrated
/// values, how far the torques moved the link (whether a link pulled far from its description is where the spreads
/// miss).
type PriorDistance = BTreeMap<String, f64>;

/// The [`PriorDistance`] of each of `points` (their means) under the prior of `nominal`.
fn prior_distances<const N: usize>(
    nominal: &dynforge_robot::Model,
    spread: Spread,
    points: [&CoordinatePrior; N],
) -> Result<[PriorDistance; N]> {
    let prior = CoordinatePrior::of(nominal, spread)?;
    Ok(points.map(|at| {
        let z = prior.whiten(&at.mean);
        nominal
            .links()
            .iter()
            .enumerate()
            .map(|(l, link)| (link.name.clone(), z.rows(COORDINATES * l, COORDINATES).norm_squared()))
            .collect()
    }))
}

/// A line per parameter: case, robot, name, what decided it, z, value, truth, spread, prior spread, iterations, the
/// calibration's and least squares' NRMSE, and (real arms) the truth's and the calibration's [`PriorDistance`] for
/// the parameter's link.
fn write_dump(
    out: &mut impl std::io::Write,
    case: &str,
    robot: u64,
    (id, truth): (&Identification, &Identification),
    distance: Option<(&PriorDistance, &PriorDistance)>,
) -> Result<()> {
    for (p, t) in id.parameters().into_iter().zip(truth.parameters()) {
        let e = p.estimate;
        let z = e.z(t.estimate.value);
        let link = p.name.rsplit_once('.').map_or("", |(link, _)| link);
        let of = |d: Option<&PriorDistance>| d.and_then(|d| d.get(link)).map_or(f64::NAN, |d| *d);
        let (d, m) = (of(distance.map(|d| d.0)), of(distance.map(|d| d.1)));
        writeln!(
            out,
            "{case}\t{robot}\t{}\t{:?}\t{z}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{d}\t{m}",
            p.name,
            e.decided,
            e.value,
            t.estimate.value,
            e.std,
            e.prior_std,
            id.iterations,
            id.nrmse_calibrated,
            id.nrmse_least_squares
        )?;
    }
    Ok(())
}

/// Where every parameter's z is written, when asked (`--dump`).
type Dump = Option<std::io::BufWriter<std::fs::File>>;

/// What a family's coverage is asked: the variants, the welded joints and the bag's effort noise (relative; 0 for
/// the shards as they are).
struct FamilyCase {
    robots: u64,
    fixed: Vec<String>,
    noise: f64,
}

/// Coverage over the variants of a family run directory: from each variant's first log, and from all its logs.
fn family_coverage(dir: &std::path::Path, case: &FamilyCase, dump: &mut Dump) -> Result<()> {
    let FamilyCase { robots, fixed, noise } = case;
    let (robots, noise) = (*robots, *noise);
    let manifest = dynforge_proto::manifest::Manifest::load(dir)?.context("a run directory")?;
    let family = manifest.family.context("a family's run directory (generate --urdf)")?;
    let urdf = std::fs::read_to_string(dir.join("family/robot.urdf"))?;
    // A bag's velocity is its encoder's differences: from positions, as identify takes it.
    let velocity = (noise > 0.0).then_some(VelocitySource::Positions);
    let options = Options {
        spread: family.spread,
        conditioning: Conditioning { effort: Some(EffortConvention::Held), velocity, ..Conditioning::default() },
        reading: Reading::welding(fixed),
        weld_idle: true,
        ..Options::default()
    };
    let shards = shards_by_robot(dir)?;
    for (case, first_only) in [("first log", true), ("all logs", false)] {
        let (mut zs, mut failed, mut used) = (Zs::new(), 0, 0);
        for (r, mine) in shards.iter().take(robots as usize) {
            let mut mine = mine.clone();
            if first_only {
                mine.truncate(1);
            }
            let truth = read_log(&mine[0], None, &Reading::welding(fixed))?.model;
            let mut logs = read_logs(&mine, Some((&urdf, "robot.urdf")), &Reading::welding(fixed))?;
            if noise > 0.0 {
                let degradation = bag_like(&logs, noise);
                for (k, log) in logs.iter_mut().enumerate() {
                    degradation.apply(log, *r * 16 + k as u64);
                }
            }
            match identify_read(logs, &options) {
                Ok((id, _)) => {
                    let mut at_truth = id.clone();
                    at_truth.report_values_of(&truth);
                    add(&mut zs, &id, &at_truth);
                    if let Some(out) = dump.as_mut() {
                        write_dump(out, case, *r, (&id, &at_truth), None)?;
                    }
                    used += 1;
                }
                Err(e) => {
                    failed += 1;
                    eprintln!("robot {r} ({case}): {e}");
                }
            }
        }
        eprintln!("{case}: {used} variants identified, {failed} refused");
        print(&format!("family {case}"), &mut zs);
    }
    Ok(())
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut nominals, mut seconds, mut spread) = (20u64, 30.0, Options::default().spread);
    let (mut family, mut robots, mut fixed, mut noise, mut dump) = (None, 100u64, Vec::new(), 0.0, None);
    let all = [&UR5, &PANDA];
    let mut arms = all.to_vec();
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--nominals" => nominals = value()?.parse()?,
            "--seconds" => seconds = value()?.parse()?,
            "--spread" => spread = value()?.parse()?,
            "--family" => family = Some(std::path::PathBuf::from(value()?)),
            "--robots" => robots = value()?.parse()?,
            "--fix" => fixed.push(value()?),
            "--noise" => noise = value()?.parse()?,
            "--arm" => {
                let name = value()?;
                arms = all.into_iter().filter(|a| a.name == name).collect();
                if arms.is_empty() {
                    let names: Vec<&str> = all.iter().map(|a| a.name).collect();
                    bail!("--arm {name}: the arms are {}", names.join(" and "));
                }
            }
            "--dump" => {
                let path = value()?;
                dump = Some(std::io::BufWriter::new(std::fs::File::create(&path).with_context(|| path.clone())?));
            }
            _ => bail!("unknown option {a}"),
        }
    }
    if let Some(dir) = family {
        println!("| case | parameters | decided by | n | abs(z) < 1 | abs(z) < 2 | median abs(z) |");
        println!("|---|---|---|---|---|---|---|");
        return family_coverage(&dir, &FamilyCase { robots, fixed, noise }, &mut dump);
    }
    let py = std::env::var("DYNFORGE_PYTHON").context("DYNFORGE_PYTHON: the venv of scripts/venv.sh")?;
    let dir = std::env::temp_dir().join(format!("dynforge-identify-coverage-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    println!(
        "{nominals} nominal URDFs per case drawn from the prior (spread {spread}); {seconds} s logs, held effort\n"
    );
    println!("| case | parameters | decided by | n | abs(z) < 1 | abs(z) < 2 | median abs(z) |");
    println!("|---|---|---|---|---|---|---|");
    let result =
        arms.into_iter().try_for_each(|arm| arm_coverage(&py, &dir, arm, (nominals, seconds, spread), &mut dump));
    std::fs::remove_dir_all(&dir)?;
    result
}
