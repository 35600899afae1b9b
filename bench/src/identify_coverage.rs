//! Whether the spreads `identify` reports are standard deviations, on real arms: example-robot-data's UR5 and Panda
//! logged by MuJoCo (`tests/reference/simulate_arm.py`), calibrated from nominal URDFs drawn from the prior the
//! calibration assumes (each link's log-Cholesky coordinates around the true ones with the `--spread` it is given,
//! no friction), so that the truth lies where the prior says. Each parameter's `z = (value - truth) / std` should
//! fall within 1 about 68 % of the time and within 2 about 95 %, per kind, clean and noisy (1 % effort noise, 2^17
//! encoders, velocity from encoder differences).
//!
//! Usage: DYNFORGE_PYTHON=.venv/bin/python dynforge-bench-identify-coverage [--nominals N] [--seconds S]
//! [--spread X]

use std::collections::BTreeMap;

use anyhow::{Context, Result, bail};
use dynforge_identify::calibrate::{Decided, Estimated, Identification, Options, identify_logs};
use dynforge_identify::consistent::CoordinatePrior;
use dynforge_identify::signals::{Conditioning, EffortConvention};
use dynforge_recording::log::read_log;
use dynforge_robot::rng::Rng;
use dynforge_testkit::arms::{Arm, Harness, LogKind, PANDA, UR5};

#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Every parameter of an identification with its kind: (kind, estimate).
fn parameters(id: &Identification) -> Vec<(&'static str, Estimated)> {
    let mut out = Vec::new();
    for l in &id.links {
        out.push(("mass", l.mass));
        out.extend(l.com.iter().map(|e| ("com", *e)));
        out.extend(l.inertia.iter().map(|e| ("inertia", *e)));
    }
    for j in &id.joints {
        out.extend([("friction", j.coulomb), ("friction", j.viscous)]);
    }
    out
}

/// |z| per (kind, what decided it).
type Zs = BTreeMap<(&'static str, &'static str), Vec<f64>>;

fn add(zs: &mut Zs, id: &Identification, truth: &Identification) {
    for ((kind, e), (_, t)) in parameters(id).into_iter().zip(parameters(truth)) {
        let decided = if e.decided == Decided::Torques { "torques" } else { "prior" };
        let z = e.z(t.value).abs();
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

fn arm_coverage(py: &str, dir: &std::path::Path, arm: &Arm, nominals: u64, seconds: f64, spread: f64) -> Result<()> {
    let harness = Harness::new(py.to_string(), dir, arm);
    let truth_text = std::fs::read_to_string(&harness.urdf).with_context(|| harness.urdf.clone())?;
    let fixed: Vec<String> = arm.fixed.iter().map(|s| s.to_string()).collect();
    for kind in [LogKind::Clean, LogKind::Noisy] {
        let log = harness.log(arm, 1, seconds, "held", kind, 1000.0);
        let truth = read_log(&log, Some((&truth_text, "true.urdf")), &fixed)?;
        let prior = CoordinatePrior::of(&truth.model, spread)?;
        let options = Options {
            spread,
            conditioning: Conditioning { effort: Some(EffortConvention::Held), ..Conditioning::default() },
            fixed: fixed.clone(),
        };
        let mut zs = Zs::new();
        let mut failed = 0;
        for i in 0..nominals {
            let mut rng = Rng::stream(7, &[i]);
            let nominal = prior.draw(&truth.model, || rng.normal())?;
            let (text, _) = dynforge_robot::urdf::patch_welded(&truth.document, &truth.source, &nominal, &truth.welds)?;
            match identify_logs(std::slice::from_ref(&log), Some((&text, "nominal.urdf")), &options) {
                Ok((id, _)) => {
                    let mut at_truth = id.clone();
                    at_truth.report_values_of(&truth.model);
                    // The true friction is the harness's (MuJoCo's joints), not the URDF's.
                    for j in &mut at_truth.joints {
                        let (_, c, v) = arm.friction.iter().find(|f| f.0 == j.name).context("a moving joint")?;
                        (j.coulomb.value, j.viscous.value) = (*c, *v);
                    }
                    add(&mut zs, &id, &at_truth);
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

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let (mut nominals, mut seconds, mut spread) = (20u64, 30.0, Options::default().spread);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--nominals" => nominals = value()?.parse()?,
            "--seconds" => seconds = value()?.parse()?,
            "--spread" => spread = value()?.parse()?,
            _ => bail!("unknown option {a}"),
        }
    }
    let py = std::env::var("DYNFORGE_PYTHON").context("DYNFORGE_PYTHON: the venv of scripts/venv.sh")?;
    let dir = std::env::temp_dir().join(format!("dynforge-identify-coverage-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    println!(
        "{nominals} nominal URDFs per case drawn from the prior (spread {spread}); {seconds} s logs, held effort\n"
    );
    println!("| case | parameters | decided by | n | abs(z) < 1 | abs(z) < 2 | median abs(z) |");
    println!("|---|---|---|---|---|---|---|");
    let result = [&UR5, &PANDA].into_iter().try_for_each(|arm| arm_coverage(&py, &dir, arm, nominals, seconds, spread));
    std::fs::remove_dir_all(&dir)?;
    result
}
