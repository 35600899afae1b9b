//! What a trajectory is worth and whether it keeps the bounds: its samples' information and peaks, and the scaling
//! that brings a series of free coefficients into the bounds and off the robot's own bodies.

use dynforge_robot::{Data, Model, regressor};
use nalgebra::{DMatrix, DVector};

use crate::ExciteError;
use crate::collision::SelfCollision;
use crate::information::{Information, scales};
use crate::motion::Motion;
use crate::options::Options;
use dynforge_proto::fourier::Fourier;

/// Per joint the bounds the motion keeps (position interval, speed, acceleration and effort) and the torque noise its
/// information is weighted by.
pub(crate) struct Bounds {
    pub(crate) start: Vec<f64>,
    pub(crate) lower: Vec<f64>,
    pub(crate) upper: Vec<f64>,
    pub(crate) speed: Vec<f64>,
    pub(crate) acceleration: Vec<f64>,
    pub(crate) effort: Vec<f64>,
    pub(crate) noise: Vec<f64>,
}

/// `values` for each of `n` joints: one for all or one each, every one positive and finite; `what` names them in the
/// error.
fn per_joint(values: &[f64], n: usize, what: &str) -> Result<Vec<f64>, ExciteError> {
    if !(values.len() == 1 || values.len() == n) {
        return Err(ExciteError::Option(format!(
            "{} {what} values given for {n} joints: give one for all or one per joint",
            values.len()
        )));
    }
    if let Some(v) = values.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
        return Err(ExciteError::Option(format!("{what} {v} is not positive")));
    }
    Ok((0..n).map(|j| values[if values.len() == 1 { 0 } else { j }]).collect())
}

impl Bounds {
    pub(crate) fn new(model: &Model, o: &Options) -> Result<Self, ExciteError> {
        let n = model.dof();
        let mut b = Bounds {
            start: Vec::new(),
            lower: Vec::new(),
            upper: Vec::new(),
            speed: Vec::new(),
            acceleration: per_joint(&o.acceleration, n, "acceleration limit")?,
            effort: Vec::new(),
            noise: per_joint(&o.noise, n, "torque noise")?,
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
            b.effort.push(o.effort_share * l.effort);
        }
        Ok(b)
    }
}

/// Samples one trajectory: its information (scaled) and its peaks as shares of the bounds (position, velocity,
/// acceleration, effort). The effort is the URDF's own inverse dynamics with its friction.
pub(crate) struct Sampler<'a> {
    pub(crate) model: &'a Model,
    pub(crate) bounds: &'a Bounds,
    pub(crate) scales: DVector<f64>,
    pub(crate) nominal: DVector<f64>,
    pub(crate) samples: usize,
    pub(crate) data: Data,
    /// One workspace per part of the samples summed side by side.
    pub(crate) parts: Vec<Data>,
    pub(crate) collision: Option<&'a SelfCollision>,
    /// The series' period and harmonics.
    pub(crate) period: f64,
    pub(crate) harmonics: usize,
}

/// Parts a trajectory's samples are split into, each summed on a thread of its own and added in order: a fixed
/// number, so the sums, and so the design, do not depend on the machine's cores.
const PARTS: usize = 4;

impl<'a> Sampler<'a> {
    pub(crate) fn new(
        model: &'a Model,
        bounds: &'a Bounds,
        collision: Option<&'a SelfCollision>,
        options: &Options,
        rate: f64,
    ) -> Self {
        let samples = (options.duration * rate).ceil().max(2.0 * options.harmonics as f64 + 2.0) as usize;
        Sampler {
            model,
            bounds,
            scales: DVector::from_vec(scales(model)),
            nominal: DVector::from_vec(dynforge_robot::parameters::dynamic_parameters(model)),
            samples,
            data: Data::new(model),
            parts: (0..PARTS).map(|_| Data::new(model)).collect(),
            collision,
            period: options.duration,
            harmonics: options.harmonics,
        }
    }

    pub(crate) fn sample(&mut self, f: &impl Motion, information: bool) -> (DMatrix<f64>, [f64; 4]) {
        let (model, b, scales, nominal, samples) = (self.model, self.bounds, &self.scales, &self.nominal, self.samples);
        let part = |range: std::ops::Range<usize>, data: &mut Data| {
            let n = model.dof();
            let mut w = information.then(|| Information::new(scales, &b.noise));
            let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            let mut peaks = [0.0f64; 4];
            for k in range {
                f.at(f.duration() * k as f64 / samples as f64, &mut q, &mut qd, &mut qdd);
                let y = regressor(model, data, &q, &qd, &qdd);
                let tau = y * nominal;
                for j in 0..n {
                    let d = q[j] - b.start[j];
                    let room = if d >= 0.0 { b.upper[j] - b.start[j] } else { b.start[j] - b.lower[j] };
                    peaks[0] = peaks[0].max(d.abs() / room);
                    peaks[1] = peaks[1].max(qd[j].abs() / b.speed[j]);
                    peaks[2] = peaks[2].max(qdd[j].abs() / b.acceleration[j]);
                    peaks[3] = peaks[3].max(tau[j].abs() / b.effort[j]);
                }
                if let Some(w) = w.as_mut() {
                    w.add(y);
                }
            }
            (w.map_or_else(|| DMatrix::zeros(0, 0), Information::finish), peaks)
        };
        let part = &part;
        let results: Vec<(DMatrix<f64>, [f64; 4])> = std::thread::scope(|s| {
            let handles: Vec<_> = (self.parts.iter_mut().enumerate())
                .map(|(i, data)| s.spawn(move || part(i * samples / PARTS..(i + 1) * samples / PARTS, data)))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
        });
        let mut total = results[0].clone();
        for (w, peaks) in &results[1..] {
            if information {
                total.0 += w;
            }
            total.1.iter_mut().zip(peaks).for_each(|(a, b)| *a = a.max(*b));
        }
        total
    }

    /// The first pair of bodies in contact along `f` at this sampler's rate, if any (none when collisions are not
    /// checked).
    pub(crate) fn contact(&mut self, f: &Fourier) -> Option<(usize, usize)> {
        let c = self.collision?;
        let n = self.model.dof();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        (0..self.samples).find_map(|k| {
            f.at(f.period * k as f64 / self.samples as f64, &mut q, &mut qd, &mut qdd);
            c.first_contact(self.model, &mut self.data, &q)
        })
    }

    /// `c`, or `c` with the joints that move one touching body against the other (those between them on the chain)
    /// shrunk towards the start pose, by steps of a fifth (at most 8), until no checked bodies touch along it; `Err`
    /// with the last pair in contact (`None`: the shrunk motion left the bounds). The other joints keep their
    /// motion.
    pub(crate) fn free(&mut self, mut c: Candidate) -> Result<Candidate, Option<(usize, usize)>> {
        let per_joint = Fourier::free_per_joint(self.harmonics);
        let (mut contact, mut shrunk) = (None, false);
        for _ in 0..8 {
            contact = self.contact(&self.series(&c.x));
            let Some((a, b)) = contact else {
                // The information of the motion kept, summed once, not at every shrink on the way.
                if shrunk {
                    c.information = self.sample(&self.series(&c.x), true).0;
                }
                return Ok(c);
            };
            // Body k is link k's (0: the base), moved by joints 0..k: joints a..b move b relative to a.
            c.x[a * per_joint..b * per_joint].iter_mut().for_each(|v| *v *= 0.8);
            c.peaks = self.sample(&self.series(&c.x), false).1;
            if c.peaks.iter().any(|&p| p > 1.0 + 1e-9) {
                return Err(None);
            }
            shrunk = true;
        }
        Err(contact)
    }

    /// The series of free coefficients `x`.
    pub(crate) fn series(&self, x: &[f64]) -> Fourier {
        Fourier::from_free(self.period, &self.bounds.start, self.harmonics, x)
    }

    /// `c` shrunk by steps of 1 % (at most 50) until, at this sampler's rate, its effort keeps the bounds and no
    /// checked bodies touch (a motion that grazes a body between coarser samples is shrunk off it); its peaks at
    /// this rate.
    pub(crate) fn settle(&mut self, c: &mut Candidate) -> Result<(), ExciteError> {
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
    pub(crate) fn clearance(&mut self, check: &SelfCollision, f: &Fourier) -> (f64, String) {
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

    /// Per joint the largest share of its position room, speed and acceleration bounds `f` reaches at the samples
    /// (each depends on that joint's coefficients alone, in proportion).
    pub(crate) fn kinematic_peaks(&self, f: &impl Motion) -> Vec<[f64; 3]> {
        self.kinematic_peaks_at(f, self.samples)
    }

    /// [`Sampler::kinematic_peaks`] at `samples` evenly spaced instants.
    pub(crate) fn kinematic_peaks_at(&self, f: &impl Motion, samples: usize) -> Vec<[f64; 3]> {
        let n = self.model.dof();
        let b = self.bounds;
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        let mut peaks = vec![[0.0f64; 3]; n];
        for k in 0..samples {
            f.at(f.duration() * k as f64 / samples as f64, &mut q, &mut qd, &mut qdd);
            for (j, p) in peaks.iter_mut().enumerate() {
                let d = q[j] - b.start[j];
                let room = if d >= 0.0 { b.upper[j] - b.start[j] } else { b.start[j] - b.lower[j] };
                p[0] = p[0].max(d.abs() / room);
                p[1] = p[1].max(qd[j].abs() / b.speed[j]);
                p[2] = p[2].max(qdd[j].abs() / b.acceleration[j]);
            }
        }
        peaks
    }

    /// The series of free coefficients `x` scaled so that it keeps every bound, with its information and peaks:
    /// each joint's coefficients scaled alone until the first of its kinematic bounds binds (so one joint's tight
    /// bound does not hold the others back), then all together until the effort fits (with gravity in it, the
    /// effort does not scale in proportion: it is shrunk by steps). `None` when a joint does not move or even a
    /// tenth of the motion needs more effort than the bounds allow.
    pub(crate) fn fit(&mut self, x: &[f64]) -> Option<Candidate> {
        // Between samples a trigonometric polynomial of degree N sampled M > 2N times per period rises at most by
        // sec(pi N / M) over its largest sample (Ehlich and Zeller, 1964): so the kinematic bounds hold at every
        // instant, not only at the samples.
        let between = 1.0 / (std::f64::consts::PI * self.harmonics as f64 / self.samples as f64).cos();
        let per_joint = Fourier::free_per_joint(self.harmonics);
        let mut xs = x.to_vec();
        for (j, p) in self.kinematic_peaks(&self.series(x)).iter().enumerate() {
            let peak = p[0].max(p[1]).max(p[2]) * between;
            if !(peak > 0.0 && peak.is_finite()) {
                return None;
            }
            xs[j * per_joint..(j + 1) * per_joint].iter_mut().for_each(|v| *v /= peak);
        }
        let (period, start, harmonics) = (self.period, self.bounds.start.as_slice(), self.harmonics);
        let series = |x: &Vec<f64>| Fourier::from_free(period, start, harmonics, x);
        let shrink = |x: &mut Vec<f64>| x.iter_mut().for_each(|v| *v *= EFFORT_STEP);
        let fits = |peaks: &[f64; 4]| peaks.iter().all(|&p| p <= 1.0 + 1e-9);
        let (x, information, peaks) = self.shrink_until(xs, series, shrink, EFFORT_STEPS, fits)?;
        Some(Candidate { x, information, peaks })
    }

    /// `state`, or `state` put through `shrink` (at most `steps - 1` times), until the peaks of its `motion` `fits`
    /// (the effort, with gravity in it, does not scale in proportion: it is found by steps), with that motion's
    /// information and peaks; `None` if it never fits. The first try sums the information as it goes (most fit at
    /// once); after it, the peaks alone are sampled until one fits.
    pub(crate) fn shrink_until<T, M: Motion>(
        &mut self,
        mut state: T,
        motion: impl Fn(&T) -> M,
        shrink: impl Fn(&mut T),
        steps: usize,
        fits: impl Fn(&[f64; 4]) -> bool,
    ) -> Option<(T, DMatrix<f64>, [f64; 4])> {
        for step in 0..steps {
            let m = motion(&state);
            if step == 0 {
                let (information, peaks) = self.sample(&m, true);
                if fits(&peaks) {
                    return Some((state, information, peaks));
                }
            } else if fits(&self.sample(&m, false).1) {
                let (information, peaks) = self.sample(&m, true);
                return Some((state, information, peaks));
            }
            shrink(&mut state);
        }
        None
    }
}

/// The common factor the effort fit shrinks a motion by per step, and the most steps (down to a tenth).
const EFFORT_STEP: f64 = 0.95;
const EFFORT_STEPS: usize = 45;

/// A set of free coefficients kept within the bounds, with its information and peaks.
#[derive(Debug, Clone)]
pub(crate) struct Candidate {
    pub(crate) x: Vec<f64>,
    pub(crate) information: DMatrix<f64>,
    pub(crate) peaks: [f64; 4],
}
