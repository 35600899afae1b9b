//! `dynforge calibrate` against `dynforge identify` and the URDF as given, on real arms: example-robot-data's UR5
//! and Panda simulated by MuJoCo (`tests/reference/simulate_arm.py`) running excitations `dynforge excite`
//! designed, logged as a driver writes them (1 % effort noise, 2^17-count encoders, velocity from encoder
//! differences, sampled effort), calibrated from nominal URDFs. Per kind of parameter:
//! - coverage: the share of parameters within one and two printed standard deviations of the truth (identify's
//!   spreads, and calibrate's, which the robot's family measured);
//! - error: the RMS error over the truth's RMS, of the URDF as given, of identify and of calibrate, over every
//!   parameter and over those the torques cannot tell (decided by the prior);
//! - the torque NRMSE of each on a held-out motion.
//!
//! Nominal URDFs: `perturb` (every inertial off by a random 20-30 %, as the tests' users have them) or `prior` (drawn
//! from the prior the calibration assumes, spread 0.3 around the truth: where the spreads must hold).
//!
//! Usage: DYNFORGE_PYTHON=.venv/bin/python dynforge-bench-calibrate --dynforge target/release/dynforge
//! [--nominals N] [--nominal perturb|prior] [--robots 64] [--arms ur5,panda] [--work DIR] [--identify-only]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use dynforge_identify::calibrate::Kind;
use dynforge_proto::spread::Spread;
use dynforge_recording::Reading;
use dynforge_recording::log::read_log;
use dynforge_robot::parameters::{standard_names, standard_parameters};
use dynforge_robot::prior::CoordinatePrior;
use dynforge_robot::rng::Rng;
use dynforge_testkit::arms::{Arm, Harness, PANDA, UR5};
use serde_json::{Value, json};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

struct Settings {
    dynforge: PathBuf,
    nominals: u64,
    prior_draws: bool,
    robots: u64,
    work: PathBuf,
    /// Identify only (its columns repeated as calibrate's): minutes instead of a family per nominal.
    identify_only: bool,
}

/// One parameter of one calibration: its kind, whether the prior decided it (in calibrate's judgement), the
/// truth, the nominal, and (value, std, log scale) of identify and of calibrate.
struct Row {
    kind: &'static str,
    prior: bool,
    truth: f64,
    nominal: f64,
    identify: (f64, f64, bool),
    calibrate: (f64, f64, bool),
    /// Calibrate's value with the spread before the family's factor (identify's at calibrate's spread).
    unscaled: (f64, f64, bool),
}

/// One parameter of a `--json` identification: value, standard deviation (of the logarithm when `log`), whether the
/// prior decided it, and the URDF's value.
struct Reported {
    value: f64,
    std: f64,
    log: bool,
    prior: bool,
    urdf: f64,
}

/// Every parameter of a `--json` identification in order.
fn estimates(v: &Value) -> Result<Vec<Reported>> {
    let e = |x: &Value| -> Result<Reported> {
        let f = |k: &str| x[k].as_f64().with_context(|| format!("{k} in {x}"));
        Ok(Reported {
            value: f("value")?,
            std: f("std")?,
            log: x["scale"] == "log",
            prior: x["decided"] == "prior",
            urdf: f("urdf")?,
        })
    };
    dynforge_testkit::json_parameters(v).context("links and joints")?.into_iter().map(e).collect()
}

fn z((value, std, log): (f64, f64, bool), truth: f64) -> f64 {
    match log {
        true => (value / truth).ln() / std,
        false => (value - truth) / std,
    }
}

fn dynforge(s: &Settings, args: &[&str]) -> Result<Value> {
    let out = Command::new(&s.dynforge).args(args).output().with_context(|| s.dynforge.display().to_string())?;
    if !out.status.success() {
        bail!("dynforge {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    }
    Ok(serde_json::from_slice(&out.stdout)?)
}

fn arm_case(py: &str, s: &Settings, arm: &Arm, table: &mut Vec<String>) -> Result<()> {
    let dir = s.work.join(arm.name);
    std::fs::create_dir_all(&dir)?;
    let harness = Harness::new(py.to_string(), &dir, arm);
    let fixed: Vec<String> = arm.fixed.iter().map(|j| j.to_string()).collect();
    let mut fix_args: Vec<&str> = Vec::new();
    for j in &fixed {
        fix_args.extend(["--fix", j.as_str()]);
    }
    // The Panda's mimic finger goes with the one welded.
    let excite = dir.join("excitation");
    if !excite.join("report.md").exists() {
        let mut args = vec!["excite", "--urdf", &harness.urdf, "--out"];
        let out = excite.display().to_string();
        args.push(&out);
        args.extend(["--count", "4", "--duration", "10", "--acceleration", "5"]);
        args.extend(&fix_args);
        let status = Command::new(&s.dynforge).args(&args).status()?;
        if !status.success() {
            bail!("excite for {} failed", arm.name);
        }
    }
    let mut bags = Vec::new();
    for k in 0..4 {
        let out = dir.join(format!("excitation-{k}.mcap"));
        if !out.exists() {
            harness.excitation_log(arm, &excite.join(format!("excitation-{k}.json")), 10 + k, &out);
        }
        bags.push(out);
    }
    let held = dir.join("held-out.mcap");
    if !held.exists() {
        harness.run(
            &[],
            &json!({
                "urdf": harness.urdf, "friction": arm.friction_json(), "seed": 99, "duration": 20.0, "rate": 1000.0,
                "effort": "sampled", "out": held,
            }),
        );
    }
    let truth_text = std::fs::read_to_string(&harness.urdf)?;
    let truth_log = read_log(&bags[0], Some((&truth_text, "true.urdf")), &Reading::welding(&fixed))?;
    let names = standard_names(&truth_log.model);
    let mut truth = standard_parameters(&truth_log.model);
    for (name, value) in names.iter().zip(truth.iter_mut()) {
        if let Some((joint, field)) = name.rsplit_once('.')
            && let Some((_, c, v)) = arm.friction.iter().find(|f| f.0 == joint)
        {
            *value = if field == "coulomb" { *c } else { *v };
        }
    }
    let prior = CoordinatePrior::of(&truth_log.model, Spread::uniform(0.3))?;
    let mut rows: Vec<Row> = Vec::new();
    let mut held_out: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
    let bag_args: Vec<String> = bags.iter().map(|b| b.display().to_string()).collect();
    for i in 0..s.nominals {
        let nominal = dir.join(format!("nominal-{i}.urdf"));
        if s.prior_draws {
            let mut rng = Rng::stream(11, &[i]);
            let drawn = prior.draw(&truth_log.model, || rng.normal())?;
            let text = truth_log.urdf_of(&drawn)?;
            std::fs::write(&nominal, text)?;
        } else {
            harness.run(
                &["--perturb"],
                &json!({"urdf": harness.urdf, "seed": 100 + i, "low": 0.2, "high": 0.3, "out": nominal}),
            );
        }
        let nominal_s = nominal.display().to_string();
        let held_s = held.display().to_string();
        let run = |command: &str, out: &Path, extra: &[&str]| {
            let out_s = out.display().to_string();
            let mut args: Vec<&str> = vec![command];
            args.extend(bag_args.iter().map(String::as_str));
            args.extend(["--urdf", &nominal_s, "--holdout", &held_s, "--out", &out_s, "--json"]);
            args.extend(&fix_args);
            args.extend(extra);
            dynforge(s, &args)
        };
        let started = std::time::Instant::now();
        let cal_dir = s.work.join("cache").display().to_string();
        let robots = s.robots.to_string();
        let excite_s = excite.display().to_string();
        let identified = run("identify", &dir.join(format!("identify-{i}.urdf")), &[])?;
        let calibrated = match s.identify_only {
            true => identified.clone(),
            false => run(
                "calibrate",
                &dir.join(format!("calibrate-{i}.urdf")),
                &["--excitation", &excite_s, "--cache", &cal_dir, "--robots", &robots],
            )?,
        };
        let seconds = started.elapsed().as_secs_f64();
        eprintln!("{} nominal {i}: {seconds:.0} s", arm.name);
        let (c, d) = (estimates(&calibrated)?, estimates(&identified)?);
        if c.len() != truth.len() || d.len() != truth.len() {
            bail!("{} parameters, {} and {} reported", truth.len(), c.len(), d.len());
        }
        let factors = calibrated["family"]["spreads"]["parameters"].as_array();
        if factors.is_none() && !s.identify_only {
            bail!("calibrate's JSON holds no family spreads");
        }
        for (k, name) in names.iter().enumerate() {
            let applied = match factors {
                Some(f) => f[k]["factor"].as_f64().context("a factor")?.max(1.0),
                None => 1.0,
            };
            let (c, d) = (&c[k], &d[k]);
            rows.push(Row {
                unscaled: (c.value, c.std / applied, c.log),
                kind: Kind::of(name).name(),
                prior: c.prior,
                truth: truth[k],
                nominal: c.urdf,
                identify: (d.value, d.std, d.log),
                calibrate: (c.value, c.std, c.log),
            });
        }
        for (who, v) in [
            ("URDF as given", &calibrated["held_out"]["nrmse_urdf"]),
            ("identify", &identified["held_out"]["nrmse_calibrated"]),
            ("calibrate", &calibrated["held_out"]["nrmse_calibrated"]),
        ] {
            held_out.entry(who).or_default().push(v.as_f64().context("held-out NRMSE")?);
        }
    }
    let case = format!(
        "{} ({} nominals, {})",
        arm.name,
        s.nominals,
        if s.prior_draws { "prior draws" } else { "20-30 % off" }
    );
    for k in ["mass", "com", "inertia", "friction"] {
        for (set, keep) in [("all", None), ("torques", Some(false)), ("prior", Some(true))] {
            let r: Vec<&Row> = rows.iter().filter(|r| r.kind == k && keep.is_none_or(|p| r.prior == p)).collect();
            if r.is_empty() {
                continue;
            }
            let within = |f: &dyn Fn(&Row) -> f64, c: f64| {
                100.0 * r.iter().filter(|x| f(x).abs() < c).count() as f64 / r.len() as f64
            };
            let zi = |x: &Row| z(x.identify, x.truth);
            let zc = |x: &Row| z(x.calibrate, x.truth);
            let zu = |x: &Row| z(x.unscaled, x.truth);
            let t2: f64 = r.iter().map(|x| x.truth * x.truth).sum();
            let rel = |f: &dyn Fn(&Row) -> f64| (r.iter().map(|x| (f(x) - x.truth).powi(2)).sum::<f64>() / t2).sqrt();
            table.push(format!(
                "| {case} | {k} | {set} | {} | {:.0} / {:.0} % | {:.0} / {:.0} % | {:.0} / {:.0} % | {:.3} | {:.3} | {:.3} |",
                r.len(),
                within(&zi, 1.0),
                within(&zi, 2.0),
                within(&zu, 1.0),
                within(&zu, 2.0),
                within(&zc, 1.0),
                within(&zc, 2.0),
                rel(&|x| x.nominal),
                rel(&|x| x.identify.0),
                rel(&|x| x.calibrate.0),
            ));
        }
    }
    let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
    table.push(format!(
        "| {case} | held-out torque NRMSE (mean) | | | | URDF as given {:.4} | identify {:.4} | calibrate {:.4} | | |",
        mean(&held_out["URDF as given"]),
        mean(&held_out["identify"]),
        mean(&held_out["calibrate"])
    ));
    Ok(())
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let mut s = Settings {
        dynforge: PathBuf::from("target/release/dynforge"),
        nominals: 10,
        prior_draws: false,
        robots: 64,
        work: std::env::temp_dir().join("dynforge-bench-calibrate"),
        identify_only: false,
    };
    let mut arms = vec!["ur5".to_string(), "panda".to_string()];
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--dynforge" => s.dynforge = value()?.into(),
            "--nominals" => s.nominals = value()?.parse()?,
            "--nominal" => {
                s.prior_draws = match value()?.as_str() {
                    "prior" => true,
                    "perturb" => false,
                    other => bail!("--nominal {other}: perturb or prior"),
                }
            }
            "--robots" => s.robots = value()?.parse()?,
            "--arms" => arms = value()?.split(',').map(String::from).collect(),
            "--work" => s.work = value()?.into(),
            "--identify-only" => s.identify_only = true,
            _ => bail!("unknown option {a}"),
        }
    }
    let py = std::env::var("DYNFORGE_PYTHON").context("DYNFORGE_PYTHON: the venv of scripts/venv.sh")?;
    let mut table = vec![
        "| case | kind | decided by | n | identify within 1 / 2 std | before the family's factors | calibrate | error: URDF as given | identify | calibrate |".to_string(),
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|".to_string(),
    ];
    for name in &arms {
        let arm = match name.as_str() {
            "ur5" => &UR5,
            "panda" => &PANDA,
            other => bail!("--arms: ur5 or panda, not {other}"),
        };
        arm_case(&py, &s, arm, &mut table)?;
    }
    println!("{}", table.join("\n"));
    Ok(())
}
