//! The search for excitations: per trajectory a (1+1) evolution strategy over the free Fourier coefficients, each
//! candidate scaled joint by joint into the limits before it is judged, judged by the D-optimality of all
//! trajectories' information together (so the second trajectory excites what the first left weak) and, less, by its
//! own. It starts from the best of several random series, and ends with what it is worth beside random multi-sines
//! within the same limits and what a looser acceleration limit would buy.

use dynforge_robot::Model;
use dynforge_robot::rng::Rng;
use nalgebra::DMatrix;

use crate::ExciteError;
use crate::baseline::{MultiSines, multisines};
use crate::collision::SelfCollision;
use crate::information::{Base, Quality};
use crate::options::{DENSE_RATE, Options};
use crate::sampler::{Bounds, Candidate, Sampler};
use crate::tours::tour_information;
use dynforge_proto::fourier::Fourier;

/// A designed set of excitations, with the quality of each alone and of all together, beside what it is worth: random
/// multi-sines within the same limits, the generator's tours, and the same design under a looser acceleration limit.
#[derive(Debug, Clone)]
pub struct Design {
    pub trajectories: Vec<Fourier>,
    pub alone: Vec<Quality>,
    pub together: Quality,
    /// Random multi-sines scaled joint by joint into the same bounds (`None` if too few fit the effort limits).
    pub multisines: Option<MultiSines>,
    /// The trajectories searched again under [`LOOSER`] times the acceleration limit, together.
    pub looser: Quality,
    /// The dataset generator's waypoint tours on this robot for the same total duration, if waypoints were found.
    pub tours: Option<Quality>,
    /// Information of all trajectories together (scaled parameters), its base, and the scales.
    pub information: DMatrix<f64>,
    pub base: Base,
    pub scales: Vec<f64>,
    /// Per trajectory the peaks reached, as shares of the limits: position, velocity, acceleration, effort.
    pub peaks: Vec<[f64; 4]>,
    /// When self-collision was checked: how far apart the bodies stayed.
    pub clearance: Option<Clearance>,
}

/// How far apart a design keeps the robot's bodies.
#[derive(Debug, Clone)]
pub struct Clearance {
    /// Per trajectory the smallest distance between checked bodies [m] and the pair's names.
    pub closest: Vec<(f64, String)>,
    /// Pairs of bodies checked.
    pub pairs: usize,
    /// The distance below which bodies counted as touching [m].
    pub padding: f64,
}

/// The factor on the acceleration limit the report prices: what the design would gain were the limit this much
/// looser.
pub const LOOSER: f64 = 2.0;

/// The pose every trajectory of `options` starts and ends at.
pub fn start_pose(model: &Model, options: &Options) -> Result<Vec<f64>, ExciteError> {
    check(model, options)?;
    Ok(Bounds::new(model, options)?.start)
}

/// Designs `options.count` excitations for `model` (self-collision not checked).
pub fn design(model: &Model, options: &Options) -> Result<Design, ExciteError> {
    design_with(model, options, None, |_, _| {})
}

/// [`design`], free of the self-collisions `collision` checks if given, calling `progress(done, total)` as
/// candidates are judged.
pub fn design_with(
    model: &Model,
    options: &Options,
    collision: Option<&SelfCollision>,
    mut progress: impl FnMut(usize, usize),
) -> Result<Design, ExciteError> {
    check(model, options)?;
    let bounds = Bounds::new(model, options)?;
    let mut sampler = Sampler::new(model, &bounds, collision, options, options.rate);
    let scales: Vec<f64> = sampler.scales.iter().copied().collect();
    let mut current = random_starts(&mut sampler, options)?;
    let base = Base::of(&together(&current, scales.len()));

    let (searched, priced) =
        (options.count * options.evaluations, options.count * (options.evaluations / LOOSER_SHARE));
    improve_each(&mut sampler, &mut current, options.evaluations, &base, (options.seed, SEARCH), |e| {
        progress(e, searched + priced)
    });
    // The effort, not a trigonometric polynomial, is checked again at 1 kHz (the rate drivers run at), and so is
    // self-collision: a point of the arm moves millimetres between samples there, so what passes there passes in
    // between.
    let mut dense = Sampler::new(model, &bounds, collision, options, DENSE_RATE);
    for c in current.iter_mut() {
        dense.settle(c)?;
        let f = sampler.series(&c.x);
        c.information = sampler.sample(&f, true).0;
    }
    let information = together(&current, scales.len());
    let multisines = multisines(&mut sampler, &base, options.count, options.seed);
    let looser = looser(model, collision, options, &base, &current, |e| progress(searched + e, searched + priced))?;
    let clearance = collision.map(|check| {
        let closest = current.iter().map(|c| sampler.clearance(check, &sampler.series(&c.x))).collect();
        Clearance { closest, pairs: check.pairs(), padding: check.padding() }
    });
    let tours = tour_information(
        model,
        collision,
        &scales,
        &bounds.noise,
        (options.count as f64 * options.duration, options.rate),
        options.seed,
    )
    .map(|w| Quality::of(&base, &w));
    Ok(Design {
        tours,
        clearance,
        alone: current.iter().map(|c| Quality::of(&base, &c.information)).collect(),
        together: Quality::of(&base, &information),
        multisines,
        looser,
        peaks: current.iter().map(|c| c.peaks).collect(),
        trajectories: current.iter().map(|c| sampler.series(&c.x)).collect(),
        information,
        base,
        scales,
    })
}

/// Share of the design's evaluations spent pricing a looser acceleration limit.
const LOOSER_SHARE: usize = 10;

/// The quality `design` reaches together under [`LOOSER`] times the acceleration limit (the other bounds and the
/// self-collision check kept): each trajectory searched again from where it is (feasible there too) with a tenth of
/// the evaluations. What the limit costs this design, at least.
fn looser(
    model: &Model,
    collision: Option<&SelfCollision>,
    options: &Options,
    base: &Base,
    design: &[Candidate],
    progress: impl FnMut(usize),
) -> Result<Quality, ExciteError> {
    let looser = Options { acceleration: options.acceleration.iter().map(|a| LOOSER * a).collect(), ..options.clone() };
    let bounds = Bounds::new(model, &looser)?;
    let mut sampler = Sampler::new(model, &bounds, collision, options, options.rate);
    let mut set = design.to_vec();
    improve_each(&mut sampler, &mut set, options.evaluations / LOOSER_SHARE, base, (options.seed, PRICING), progress);
    Ok(Quality::of(base, &together(&set, base.basis.nrows())))
}

/// The random streams of the search and of the looser limit's pricing (per trajectory `k`: `[k, stream]`).
const SEARCH: u64 = 1;
const PRICING: u64 = 3;

/// Each trajectory of `set` in turn improved by [`improve`] with the others held, `evaluations` candidates each, its
/// steps drawn from the stream `[k, stream]` of `seed`; `progress(done)` counts the candidates of all of them.
fn improve_each(
    sampler: &mut Sampler<'_>,
    set: &mut [Candidate],
    evaluations: usize,
    base: &Base,
    (seed, stream): (u64, u64),
    mut progress: impl FnMut(usize),
) {
    for k in 0..set.len() {
        let others = together(set, base.basis.nrows()) - &set[k].information;
        let mut rng = Rng::stream(seed, &[k as u64, stream]);
        let report = |e: usize| progress(k * evaluations + e);
        set[k] = improve(sampler, evaluations, base, &others, set[k].clone(), &mut rng, report);
    }
}

/// The information of all of `set` together (`p` parameters).
fn together(set: &[Candidate], p: usize) -> DMatrix<f64> {
    set.iter().fold(DMatrix::zeros(p, p), |acc, c| acc + &c.information)
}

/// Random series drawn per trajectory for its start; the best (with the starts before it) is kept.
const START_DRAWS: usize = 8;

/// Random starts, one per trajectory, each the best of [`START_DRAWS`] series fitted into the bounds and free of
/// collisions, judged with the starts before it (its base: that of all draws so far). Harmonic `l`'s coefficients
/// are drawn with a spread of `1 / l`, so each harmonic adds as much acceleration: white coefficients would spend
/// the acceleration limit on the highest harmonic.
fn random_starts(sampler: &mut Sampler<'_>, options: &Options) -> Result<Vec<Candidate>, ExciteError> {
    let n = sampler.model.dof();
    let per_joint = Fourier::free_per_joint(options.harmonics);
    let p = sampler.scales.len();
    let mut current: Vec<Candidate> = Vec::with_capacity(options.count);
    let mut last_contact = None;
    let mut everything = DMatrix::zeros(p, p);
    for k in 0..options.count {
        let mut rng = Rng::stream(options.seed, &[k as u64, 0]);
        let mut drawn = Vec::new();
        for _ in 0..4 * START_DRAWS {
            let x: Vec<f64> =
                (0..n * per_joint).map(|i| rng.normal() / (1 + i % (options.harmonics - 1)) as f64).collect();
            let fitted = sampler.fit(&x).and_then(|c| sampler.free(c).map_err(|pair| last_contact = pair).ok());
            drawn.extend(fitted);
            if drawn.len() == START_DRAWS {
                break;
            }
        }
        drawn.iter().for_each(|c| everything += &c.information);
        let base = Base::of(&everything);
        let held = together(&current, p);
        let best = drawn.into_iter().max_by(|a, b| {
            let judge = |c: &Candidate| Quality::of(&base, &(&held + &c.information)).log_det;
            judge(a).total_cmp(&judge(b))
        });
        let why = || match (last_contact, sampler.collision) {
            (Some(pair), Some(c)) => ExciteError::Collision(c.describe(pair)),
            _ => ExciteError::Infeasible,
        };
        current.push(best.ok_or_else(why)?);
    }
    Ok(current)
}

/// Highest harmonic a design may have [Hz]: past a geared arm's joint bandwidth (a few Hz), where a series would be
/// scaled down to nothing by the acceleration and effort limits and identify nothing (a 1 ms `--duration`).
pub const MAX_FREQUENCY: f64 = 10.0;

/// Most samples of one trajectory the design evaluates (each candidate of the search samples it whole): about 5.5 h
/// at its 50 Hz, past any excitation a robot runs and short of an unbounded search.
pub const MAX_DESIGN_SAMPLES: f64 = 1e6;

/// Most samples of one trajectory written at the user's rate (the CSV and the MCAP hold them all): 10 s at 1 MHz, or
/// 2.8 h at 1 kHz, about 1 GB of CSV for a 6-joint arm.
pub const MAX_WRITTEN_SAMPLES: f64 = 1e7;

fn check(model: &Model, options: &Options) -> Result<(), ExciteError> {
    let n = model.dof();
    if n == 0 {
        return Err(ExciteError::Option("the robot has no moving joint".into()));
    }
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if options.harmonics < 2 || options.count == 0 || !positive(options.duration) || !positive(options.rate) {
        return Err(ExciteError::Option(
            "need at least 2 harmonics, 1 trajectory, a positive duration and rate".into(),
        ));
    }
    let highest = options.harmonics as f64 / options.duration;
    if highest > MAX_FREQUENCY {
        return Err(ExciteError::Option(format!(
            "{} harmonics over {} s put the highest at {highest:.3e} Hz, past the {MAX_FREQUENCY} Hz an arm's joints \
             follow: give a longer --duration or fewer --harmonics",
            options.harmonics, options.duration
        )));
    }
    if options.duration * options.rate > MAX_DESIGN_SAMPLES {
        return Err(ExciteError::Option(format!(
            "a duration of {} s is {:.1e} samples per trajectory at the design's {} Hz, more than the {MAX_DESIGN_SAMPLES:e} \
             a design evaluates (hours of motion): give a shorter --duration",
            options.duration,
            options.duration * options.rate,
            options.rate
        )));
    }
    match &options.start {
        Some(s) if s.len() != n => {
            Err(ExciteError::Option(format!("the start pose has {} values for {n} joints", s.len())))
        }
        _ => Ok(()),
    }
}

/// Weight of a trajectory's own D-optimality beside the set's in what the search maximizes: a trajectory that only
/// fills the others' gaps identifies little alone, and a log may be lost or run alone. On the Panda, 0.5 lifted the
/// weakest trajectory alone from 2.2x to 2.7x the best random multi-sine's covariance trace, the set unchanged.
const ALONE: f64 = 0.5;

/// The (1+1) evolution strategy from `start`: a Gaussian step relative to each joint's coefficients' size, kept when
/// the set's D-optimality (with `others` held) plus [`ALONE`] times the trajectory's own rises; the step grows on
/// success and shrinks on failure (Rechenberg's rule, roughly one success in five at equilibrium).
fn improve(
    sampler: &mut Sampler<'_>,
    evaluations: usize,
    base: &Base,
    others: &DMatrix<f64>,
    start: Candidate,
    rng: &mut Rng,
    mut progress: impl FnMut(usize),
) -> Candidate {
    let judge = |w: &DMatrix<f64>| Quality::of(base, &(others + w)).log_det + ALONE * Quality::of(base, w).log_det;
    let per_joint = Fourier::free_per_joint(sampler.harmonics);
    let mut best_value = judge(&start.information);
    let mut best = start;
    let mut step = 0.3;
    for e in 0..evaluations {
        if e % 50 == 0 {
            progress(e);
        }
        // Each joint's step is relative to its own coefficients' size: their bounds differ by joint.
        let x: Vec<f64> = (best.x.chunks(per_joint))
            .flat_map(|block| {
                let size = (block.iter().map(|v| v * v).sum::<f64>() / per_joint as f64).sqrt();
                block.iter().map(move |v| (v, step * size))
            })
            .map(|(v, sigma)| v + sigma * rng.normal())
            .collect();
        // The collision check costs more than the judging: only a candidate that would be kept is checked, and the
        // one it leaves (shrunk if it touched) is judged again.
        let kept = sampler
            .fit(&x)
            .filter(|c| judge(&c.information) > best_value)
            .and_then(|c| sampler.free(c).ok())
            .map(|c| (judge(&c.information), c))
            .filter(|(value, _)| *value > best_value);
        match kept {
            Some((value, candidate)) => {
                best_value = value;
                best = candidate;
                step = (step * 1.5).min(2.0);
            }
            _ => step = (step * 0.9).max(1e-3),
        }
    }
    best
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::information::expected_std;
    use crate::motion::Motion;

    /// Three joints with different velocity and position limits: a vertical yaw, a shoulder against gravity, a
    /// light wrist.
    pub(crate) fn arm() -> Model {
        let link = |name: &str, mass: f64| {
            format!(
                r#"<link name="{name}"><inertial><origin xyz="0 0 0.15"/><mass value="{mass}"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.005"/></inertial></link>"#
            )
        };
        let joint = |name: &str, parent: &str, child: &str, axis: &str, range: f64, velocity: f64| {
            format!(
                r#"<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/><origin xyz="0 0 0.3"/><axis xyz="{axis}"/><limit lower="-{range}" upper="{range}" effort="300" velocity="{velocity}"/></joint>"#
            )
        };
        let urdf = format!(
            r#"<robot name="three"><link name="base"/>{}{}{}{}{}{}</robot>"#,
            link("a", 3.0),
            link("b", 2.0),
            link("c", 0.5),
            joint("yaw", "base", "a", "0 0 1", 2.5, 1.5),
            joint("shoulder", "a", "b", "0 1 0", 1.2, 2.0),
            joint("wrist", "b", "c", "1 0 0", 3.0, 3.0),
        );
        dynforge_robot::urdf::parse(&urdf, "three.urdf").expect("a valid URDF")
    }

    pub(crate) fn options() -> Options {
        Options { duration: 4.0, count: 2, evaluations: 40, ..Options::default() }
    }

    /// Per joint the largest share of its position room, speed and acceleration bounds reached along `f` at 1 kHz.
    fn reached(model: &Model, options: &Options, f: &Fourier) -> Vec<f64> {
        let bounds = Bounds::new(model, options).expect("valid options");
        let sampler = Sampler::new(model, &bounds, None, options, 1000.0);
        sampler.kinematic_peaks(f).iter().map(|p| p[0].max(p[1]).max(p[2])).collect()
    }

    /// Every joint of every trajectory reaches its own first binding bound (the efforts here are far inside their
    /// limits, so nothing shrinks the motion after the joint-by-joint scaling), and none passes it between the 50 Hz
    /// samples the design checks: at 1 kHz the largest share is at most sec(pi 5 / 200) = 1.0031 of its sampled peak
    /// (Ehlich and Zeller), which the scaling already allowed for, so below 1 + 1e-9.
    #[test]
    fn each_joint_reaches_its_own_first_bound_and_none_passes_it() {
        let (model, options) = (arm(), options());
        let design = design(&model, &options).expect("a design");
        for f in &design.trajectories {
            let shares = reached(&model, &options, f);
            assert!(shares.iter().all(|&s| s > 0.99 && s <= 1.0 + 1e-9), "{shares:?}");
            assert!(f.duration() == options.duration);
        }
    }

    /// One noise for all joints scales the information and nothing else: twice the noise (an exact factor of 4 on
    /// the information, a power of two) designs the same trajectories, with expected deviations exactly twice as
    /// large. One joint's noise alone changes what is judged, so the design too.
    #[test]
    fn the_noise_weighs_the_information() {
        let model = arm();
        let at = |noise: Vec<f64>| design(&model, &Options { noise, ..options() }).expect("a design");
        let (a, b, c) = (at(vec![0.1]), at(vec![0.2]), at(vec![0.1, 0.1, 5.0]));
        assert_eq!(a.trajectories, b.trajectories);
        let std = |d: &Design| expected_std(&d.base, &d.information, &d.scales);
        for (x, y) in std(&a).iter().zip(std(&b)) {
            assert!((2.0 * x - y).abs() <= 1e-12 * y, "{x} {y}");
        }
        assert_ne!(a.trajectories, c.trajectories);
        let refused = design(&model, &Options { noise: vec![0.1, 0.2], ..options() });
        assert!(
            matches!(refused, Err(ExciteError::Option(m)) if m.contains("2 torque noise values given for 3 joints"))
        );
    }
}
