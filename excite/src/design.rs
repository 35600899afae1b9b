//! The search for excitations: per trajectory a (1+1) evolution strategy over the free Fourier coefficients, each
//! candidate scaled into the limits before it is judged, judged by the D-optimality of all trajectories' information
//! together (so the second trajectory excites what the first left weak).

use dynforge_robot::rng::Rng;
use dynforge_robot::{Data, Model, regressor};
use nalgebra::{DMatrix, DVector};

use crate::ExciteError;
use crate::collision::SelfCollision;
use crate::information::{Base, Quality, add_rows, scales};
use crate::tours::tour_information;
use dynforge_proto::fourier::Fourier;

/// What to design and within which limits.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// Duration of each trajectory [s] (one period of its series).
    pub duration: f64,
    /// Trajectories.
    pub count: usize,
    /// Harmonics per joint; the highest frequency is `harmonics / duration` Hz.
    pub harmonics: usize,
    /// Pose at the start and end of every trajectory (default: the middle of each joint's range).
    pub start: Option<Vec<f64>>,
    /// Acceleration limit per joint, or one for all [rad/s^2 or m/s^2]: URDFs do not state one.
    pub acceleration: Vec<f64>,
    /// Shares of the URDF's velocity and effort limits the motion may use (the effort computed with the URDF's own
    /// parameters, which are off: keep a margin).
    pub velocity_share: f64,
    pub effort_share: f64,
    /// Share of each joint's range kept free at either end.
    pub position_margin: f64,
    /// Samples per second the information is summed over.
    pub rate: f64,
    /// Candidates judged per trajectory.
    pub evaluations: usize,
    pub seed: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            duration: 10.0,
            count: 4,
            harmonics: 5,
            start: None,
            acceleration: vec![5.0],
            velocity_share: 0.8,
            effort_share: 0.8,
            position_margin: 0.05,
            rate: 50.0,
            evaluations: 1500,
            seed: 0,
        }
    }
}

/// A designed set of excitations, with the quality of each alone and of all together, and of the random start the
/// search began from (a random multi-sine within the same limits: what the design is worth).
#[derive(Debug, Clone)]
pub struct Design {
    pub trajectories: Vec<Fourier>,
    pub alone: Vec<Quality>,
    pub together: Quality,
    pub random_together: Quality,
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

/// Per joint the bounds the motion keeps: position interval, speed, acceleration and effort.
struct Bounds {
    start: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    speed: Vec<f64>,
    acceleration: Vec<f64>,
    effort: Vec<f64>,
}

impl Bounds {
    fn new(model: &Model, o: &Options) -> Result<Self, ExciteError> {
        let n = model.dof();
        if !(o.acceleration.len() == 1 || o.acceleration.len() == n) {
            return Err(ExciteError::Option(format!(
                "{} acceleration limits given for {n} joints: give one for all or one per joint",
                o.acceleration.len()
            )));
        }
        let mut b = Bounds {
            start: Vec::new(),
            lower: Vec::new(),
            upper: Vec::new(),
            speed: Vec::new(),
            acceleration: Vec::new(),
            effort: Vec::new(),
        };
        for (j, joint) in model.joints().iter().enumerate() {
            let l = &joint.limits;
            // A continuous joint (no range) turns within a full turn around its start.
            let (lo, hi) = l.range().unwrap_or((-std::f64::consts::PI, std::f64::consts::PI));
            let margin = o.position_margin * (hi - lo);
            let start = o.start.as_ref().map_or(0.5 * (lo + hi), |s| s[j]);
            if !(start > lo + margin && start < hi - margin) {
                return Err(ExciteError::Option(format!(
                    "the start of joint '{}' ({start}) is not inside its range [{lo}, {hi}] less the margin",
                    joint.name
                )));
            }
            if !(l.velocity > 0.0 && l.effort > 0.0) {
                return Err(ExciteError::Option(format!(
                    "joint '{}' states no velocity or effort limit (velocity {}, effort {}): the URDF must give both",
                    joint.name, l.velocity, l.effort
                )));
            }
            b.start.push(start);
            b.lower.push(lo + margin);
            b.upper.push(hi - margin);
            b.speed.push(o.velocity_share * l.velocity);
            b.acceleration.push(if o.acceleration.len() == 1 { o.acceleration[0] } else { o.acceleration[j] });
            b.effort.push(o.effort_share * l.effort);
        }
        if let Some(a) = b.acceleration.iter().find(|a| a.is_nan() || **a <= 0.0) {
            return Err(ExciteError::Option(format!("acceleration limit {a} is not positive")));
        }
        Ok(b)
    }
}

/// Samples one trajectory: its information (scaled) and its peaks as shares of the bounds (position, velocity,
/// acceleration, effort). The effort is the URDF's own inverse dynamics with its friction.
struct Sampler<'a> {
    model: &'a Model,
    bounds: &'a Bounds,
    scales: DVector<f64>,
    nominal: DVector<f64>,
    samples: usize,
    data: Data,
    collision: Option<&'a SelfCollision>,
    /// The series' period and harmonics.
    period: f64,
    harmonics: usize,
}

impl Sampler<'_> {
    fn sample(&mut self, f: &Fourier, information: bool) -> (DMatrix<f64>, [f64; 4]) {
        let n = self.model.dof();
        let p = self.scales.len();
        let mut w = DMatrix::zeros(if information { p } else { 0 }, if information { p } else { 0 });
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut peaks = [0.0f64; 4];
        let b = self.bounds;
        for k in 0..self.samples {
            let t = f.period * k as f64 / self.samples as f64;
            f.at(t, &mut q, &mut qd, &mut qdd);
            let y = regressor(self.model, &mut self.data, &q, &qd, &qdd);
            let tau = y * &self.nominal;
            for j in 0..n {
                let d = q[j] - b.start[j];
                let room = if d >= 0.0 { b.upper[j] - b.start[j] } else { b.start[j] - b.lower[j] };
                peaks[0] = peaks[0].max(d.abs() / room);
                peaks[1] = peaks[1].max(qd[j].abs() / b.speed[j]);
                peaks[2] = peaks[2].max(qdd[j].abs() / b.acceleration[j]);
                peaks[3] = peaks[3].max(tau[j].abs() / b.effort[j]);
            }
            if information {
                add_rows(&mut w, y, &self.scales);
            }
        }
        (w, peaks)
    }

    /// The first pair of bodies in contact along `f` at this sampler's rate, if any (none when collisions are not
    /// checked).
    fn contact(&mut self, f: &Fourier) -> Option<(usize, usize)> {
        let c = self.collision?;
        let n = self.model.dof();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        (0..self.samples).find_map(|k| {
            f.at(f.period * k as f64 / self.samples as f64, &mut q, &mut qd, &mut qdd);
            c.first_contact(self.model, &mut self.data, &q)
        })
    }

    /// `c`, or `c` shrunk towards the start pose (by steps of a fifth, at most 8) until no checked bodies touch
    /// along it; `Err` with the last pair in contact (`None`: the shrunk motion left the bounds).
    fn free(&mut self, mut c: Candidate) -> Result<Candidate, Option<(usize, usize)>> {
        let mut contact = None;
        for _ in 0..8 {
            contact = self.contact(&self.series(&c.x));
            if contact.is_none() {
                return Ok(c);
            }
            let x: Vec<f64> = c.x.iter().map(|v| 0.8 * v).collect();
            let (information, peaks) = self.sample(&self.series(&x), true);
            if peaks.iter().any(|&p| p > 1.0 + 1e-9) {
                return Err(None);
            }
            c = Candidate { x, information, peaks };
        }
        Err(contact)
    }

    /// The series of free coefficients `x`.
    fn series(&self, x: &[f64]) -> Fourier {
        Fourier::from_free(self.period, &self.bounds.start, self.harmonics, x)
    }

    /// `c` shrunk by steps of 1 % (at most 50) until, at this sampler's rate, its effort keeps the bounds and no
    /// checked bodies touch (a motion that grazes a body between coarser samples is shrunk off it); its peaks at
    /// this rate.
    fn settle(&mut self, c: &mut Candidate) -> Result<(), ExciteError> {
        for _ in 0..50 {
            let f = self.series(&c.x);
            if self.sample(&f, false).1[3] <= 1.0 && self.contact(&f).is_none() {
                break;
            }
            c.x.iter_mut().for_each(|v| *v *= 0.99);
        }
        let f = self.series(&c.x);
        c.peaks = self.sample(&f, false).1;
        if c.peaks[3] > 1.0 {
            return Err(ExciteError::Infeasible);
        }
        match (self.contact(&f), self.collision) {
            (Some(pair), Some(check)) => Err(ExciteError::Collision(check.describe(pair))),
            _ => Ok(()),
        }
    }

    /// The smallest distance between `check`'s pairs along `f` at this sampler's rate, and the pair's names.
    fn clearance(&mut self, check: &SelfCollision, f: &Fourier) -> (f64, String) {
        let n = self.model.dof();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut best = (f64::INFINITY, String::from("no pair checked"));
        for k in 0..self.samples {
            f.at(f.period * k as f64 / self.samples as f64, &mut q, &mut qd, &mut qdd);
            if let Some((d, pair)) = check.clearance(self.model, &mut self.data, &q)
                && d < best.0
            {
                best = (d, check.describe(pair));
            }
        }
        best
    }

    /// The series of free coefficients `x` scaled so that it keeps every bound (kinematic peaks scale with the
    /// coefficients; the effort, with gravity in it, does not: it is shrunk by steps until it fits), with its
    /// information and peaks; `None` when even a tenth of it would not fit (the pose alone needs more effort).
    fn fit(&mut self, x: &[f64]) -> Option<Candidate> {
        let (_, peaks) = self.sample(&self.series(x), false);
        // Between samples a trigonometric polynomial of degree N sampled M > 2N times per period rises at most by
        // sec(pi N / M) over its largest sample (Ehlich and Zeller, 1964): so the kinematic bounds hold at every
        // instant, not only at the samples.
        let between = 1.0 / (std::f64::consts::PI * self.harmonics as f64 / self.samples as f64).cos();
        let kinematic = peaks[0].max(peaks[1]).max(peaks[2]) * between;
        if !(kinematic > 0.0 && kinematic.is_finite()) {
            return None;
        }
        let mut scale = 1.0 / kinematic;
        for _ in 0..24 {
            let xs: Vec<f64> = x.iter().map(|v| v * scale).collect();
            let (w, peaks) = self.sample(&self.series(&xs), true);
            if peaks.iter().all(|&p| p <= 1.0 + 1e-9) {
                return Some(Candidate { x: xs, information: w, peaks });
            }
            scale *= 0.9;
        }
        None
    }
}

/// Rate [Hz] the final trajectories' efforts are checked at.
const DENSE_RATE: f64 = 1000.0;

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
    let scales = scales(model);
    let nominal = DVector::from_vec(dynforge_robot::parameters::dynamic_parameters(model));
    let samples = (options.duration * options.rate).ceil().max(2.0 * options.harmonics as f64 + 2.0) as usize;
    let mut sampler = Sampler {
        model,
        bounds: &bounds,
        scales: DVector::from_vec(scales.clone()),
        nominal,
        samples,
        data: Data::new(model),
        collision,
        period: options.duration,
        harmonics: options.harmonics,
    };
    let p = scales.len();
    let sum = |c: &[Candidate]| c.iter().fold(DMatrix::zeros(p, p), |acc, c| acc + &c.information);
    let mut current = random_starts(&mut sampler, options)?;
    let random_information = sum(&current);
    let base = Base::of(&random_information);
    let random_together = Quality::of(&base, &random_information);

    // Each trajectory in turn improves the set's D-optimality with the others held.
    for k in 0..options.count {
        let others = sum(&current) - &current[k].information;
        let mut rng = Rng::stream(options.seed, &[k as u64, 1]);
        let report = |e: usize| progress(k * options.evaluations + e, options.count * options.evaluations);
        current[k] = improve(&mut sampler, options, &base, &others, current[k].clone(), &mut rng, report);
    }
    // The effort, not a trigonometric polynomial, is checked again at 1 kHz (the rate drivers run at), and so is
    // self-collision: a point of the arm moves millimetres between samples there, so what passes there passes in
    // between.
    let mut dense = Sampler {
        samples: (options.duration * DENSE_RATE).ceil() as usize,
        data: Data::new(model),
        scales: sampler.scales.clone(),
        nominal: sampler.nominal.clone(),
        ..sampler
    };
    for c in current.iter_mut() {
        dense.settle(c)?;
        let f = sampler.series(&c.x);
        c.information = sampler.sample(&f, true).0;
    }
    let information = sum(&current);
    let clearance = collision.map(|check| {
        let closest = current.iter().map(|c| sampler.clearance(check, &sampler.series(&c.x))).collect();
        Clearance { closest, pairs: check.pairs(), padding: check.padding() }
    });
    let tours = tour_information(
        model,
        collision,
        &scales,
        (options.count as f64 * options.duration, options.rate),
        options.seed,
    )
    .map(|w| Quality::of(&base, &w));
    Ok(Design {
        tours,
        clearance,
        alone: current.iter().map(|c| Quality::of(&base, &c.information)).collect(),
        together: Quality::of(&base, &information),
        random_together,
        peaks: current.iter().map(|c| c.peaks).collect(),
        trajectories: current.iter().map(|c| sampler.series(&c.x)).collect(),
        information,
        base,
        scales,
    })
}

/// Random starts, one per trajectory, fitted into the bounds and free of collisions: their information together
/// fixes the base.
fn random_starts(sampler: &mut Sampler<'_>, options: &Options) -> Result<Vec<Candidate>, ExciteError> {
    let dims = sampler.model.dof() * Fourier::free_per_joint(options.harmonics);
    let mut current = Vec::with_capacity(options.count);
    let mut last_contact = None;
    for k in 0..options.count {
        let mut rng = Rng::stream(options.seed, &[k as u64, 0]);
        let fitted = (0..20).find_map(|_| {
            let x: Vec<f64> = (0..dims).map(|_| rng.normal()).collect();
            let c = sampler.fit(&x)?;
            sampler.free(c).map_err(|pair| last_contact = pair).ok()
        });
        let why = || match (last_contact, sampler.collision) {
            (Some(pair), Some(c)) => ExciteError::Collision(c.describe(pair)),
            _ => ExciteError::Infeasible,
        };
        current.push(fitted.ok_or_else(why)?);
    }
    Ok(current)
}

/// A set of free coefficients kept within the bounds, with its information and peaks.
#[derive(Debug, Clone)]
struct Candidate {
    x: Vec<f64>,
    information: DMatrix<f64>,
    peaks: [f64; 4],
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

/// The (1+1) evolution strategy from `start`: a Gaussian step relative to the coefficients' size, kept when the
/// set's D-optimality (with `others` held) rises; the step grows on success and shrinks on failure (Rechenberg's
/// rule, roughly one success in five at equilibrium).
fn improve(
    sampler: &mut Sampler<'_>,
    options: &Options,
    base: &Base,
    others: &DMatrix<f64>,
    start: Candidate,
    rng: &mut Rng,
    mut progress: impl FnMut(usize),
) -> Candidate {
    let judge = |w: &DMatrix<f64>| Quality::of(base, &(others + w)).log_det;
    let dims = start.x.len();
    let mut best_value = judge(&start.information);
    let mut best = start;
    let mut step = 0.3;
    for e in 0..options.evaluations {
        if e % 50 == 0 {
            progress(e);
        }
        let size = best.x.iter().map(|v| v * v).sum::<f64>().sqrt() / (dims as f64).sqrt();
        let x: Vec<f64> = best.x.iter().map(|v| v + step * size * rng.normal()).collect();
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
