//! From a log's samples to what identification pairs: position, velocity, acceleration and the torque that produced
//! that acceleration, the way real drivers' logs need it.
//!
//! Velocity. A logged velocity that is measured (or simulated) is used as it is, and the acceleration is its central
//! difference. One that is absent, or is the difference of encoder positions (quantised: its acceleration is
//! noise), is replaced: the positions are low-passed by a zero-phase Butterworth filter (4th order, run forward and
//! backward, as FloBaRoID and the classical tools do) and differentiated; the effort is filtered by the same filter,
//! so motion and torque see the same attenuation and no phase between them. The cut-off is the highest frequency
//! at which the position noise the log shows (its quantisation step, or its high-frequency residue) leaves the
//! acceleration within [`ACCELERATION_NOISE`] of its own spread, or a flag's.
//!
//! Effort convention. A zero-order-hold driver logs at `t[i]` the torque it applies until `t[i+1]` ("held"); a
//! driver that samples a measured torque logs its value at `t[i]` ("sampled"). The acceleration estimate at `t[i]` is
//! a mean over `[t[i-1], t[i+1]]`, so the torque paired with it is the same mean: `(tau[i-1] + tau[i]) / 2` when held,
//! `(tau[i-1] + 2 tau[i] + tau[i+1]) / 4` when sampled (exact for a torque linear between samples). Both pairings are
//! kept until the data say which fits (`crate::log`), unless a flag names one.

use dynforge_recording::JointTrajectory;
use dynforge_robot::dynamics::sign;

/// Where the velocity comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocitySource {
    /// The log's velocity as it is.
    Logged,
    /// Differences of the low-passed positions.
    Positions,
}

/// What a logged effort is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EffortConvention {
    /// The torque applied from its stamp to the next (zero-order hold).
    Held,
    /// The torque at its stamp.
    Sampled,
}

impl EffortConvention {
    pub const ALL: [EffortConvention; 2] = [EffortConvention::Held, EffortConvention::Sampled];

    pub fn name(self) -> &'static str {
        match self {
            EffortConvention::Held => "held",
            EffortConvention::Sampled => "sampled",
        }
    }
}

/// The acceleration noise (from the position noise, after the filter) allowed, relative to the acceleration's own
/// standard deviation. A lower cut-off smears each stick of Coulomb friction over more samples (left out, and what
/// is left biased); a higher one adds noise to the regressor. On MuJoCo logs of the UR5 (2^17-count encoders, 1 %
/// effort noise) 3 % (a cut-off of ~20 Hz) gave the best held-out torques (`docs/measurements.md`).
pub const ACCELERATION_NOISE: f64 = 0.03;

/// Range of cut-offs chosen from a log [Hz], and at most this share of the sampling rate.
pub const CUTOFF_RANGE: (f64, f64) = (2.0, 100.0);
pub const CUTOFF_SHARE: f64 = 0.25;

/// How a log is turned into identification samples; `None` leaves the choice to the log.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Conditioning {
    pub velocity: Option<VelocitySource>,
    pub effort: Option<EffortConvention>,
    /// Low-pass cut-off [Hz] when the velocity comes from positions.
    pub cutoff: Option<f64>,
}

/// A segment's samples ready for the regressor: row-major `[sample][joint]` on the segment's grid. Samples 0 and
/// `len - 1` have no neighbours and are not used.
#[derive(Debug, Clone, PartialEq)]
pub struct Conditioned {
    pub joints: usize,
    pub dt: f64,
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub qdd: Vec<f64>,
    /// The velocity the viscous force is paired with: the mean over `[t[i-1], t[i+1]]`.
    pub v: Vec<f64>,
    /// The Coulomb column: `sign(qd)`, or for filtered positions `sign(qd)` through the same filter as the torque
    /// (the friction torque's jump at a reversal is smeared by the filter; an unfiltered sign beside it would not
    /// be).
    pub coulomb: Vec<f64>,
    /// The paired torque under each convention of [`EffortConvention::ALL`].
    pub tau: [Vec<f64>; 2],
    /// Samples each side of a joint's rest (or reversal) over which its own row is left out: while it sticks, its
    /// friction is whatever holds it, and a filter spreads that torque over its width.
    pub rest_margin: usize,
}

impl Conditioned {
    pub fn len(&self) -> usize {
        self.q.len() / self.joints.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.q.is_empty()
    }
}

/// What was decided for a log's velocity, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VelocityChoice {
    pub source: VelocitySource,
    /// Low-pass cut-off [Hz] (positions only).
    pub cutoff: Option<f64>,
    /// Torque rows are taken every `step` samples ([`row_step`]).
    pub step: usize,
    pub reason: String,
}

/// Samples per torque row: signals low-passed at `cutoff` (from positions or a logged velocity) hold nothing that rows
/// [`ROWS_PER_CUTOFF_PERIOD`] times per period of the cut-off miss (the filtered noise is as band-limited as the motion), so a 1 kHz log filtered at
/// 25 Hz is summed every 10th sample at a tenth of the cost and the same estimate; unfiltered signals (the logged
/// velocity) carry white effort noise that every sample averages, and are summed whole.
pub fn row_step(source: VelocitySource, cutoff: Option<f64>, dt: f64) -> usize {
    match (source, cutoff) {
        (_, Some(fc)) if fc * dt > 0.0 => ((1.0 / (ROWS_PER_CUTOFF_PERIOD * fc * dt)).floor() as usize).max(1),
        _ => 1,
    }
}

/// Rows per period of the low-pass cut-off when rows are thinned ([`row_step`]): twice Nyquist's two, so the
/// filter's roll-off above its cut-off aliases nothing that counts.
pub const ROWS_PER_CUTOFF_PERIOD: f64 = 4.0;

/// The velocity source for a segment (or the flag's), with the reason: positions when the log has no velocity or
/// when its velocity is the difference of its positions (what an encoder-only driver publishes).
pub fn choose_velocity(seg: &JointTrajectory, logged: bool, flag: Option<VelocitySource>) -> (VelocitySource, String) {
    if let Some(v) = flag {
        return (v, "as asked".into());
    }
    if !logged {
        return (VelocitySource::Positions, "the log has no velocity".into());
    }
    let share = difference_share(seg);
    if share > 0.5 {
        let why = format!(
            "the logged velocity is the difference of the logged positions in {:.0} % of samples",
            100.0 * share
        );
        return (VelocitySource::Positions, why);
    }
    (VelocitySource::Logged, "the log's velocity is measured".into())
}

/// Share of samples whose velocity equals the backward or forward difference of the positions (to rounding).
fn difference_share(seg: &JointTrajectory) -> f64 {
    let n = seg.joints();
    let len = seg.len();
    if len < 3 {
        return 0.0;
    }
    let dt = (seg.t[len - 1] - seg.t[0]) / (len - 1) as f64;
    let (mut hits, mut total) = (0usize, 0usize);
    for i in 1..len - 1 {
        for j in 0..n {
            let v = seg.qd[i * n + j];
            let back = (seg.q[i * n + j] - seg.q[(i - 1) * n + j]) / dt;
            let forward = (seg.q[(i + 1) * n + j] - seg.q[i * n + j]) / dt;
            if v == 0.0 && back == 0.0 {
                continue;
            }
            let close = |d: f64| (v - d).abs() <= 1e-6 * d.abs().max(v.abs()) + 1e-12;
            total += 1;
            hits += usize::from(close(back) || close(forward));
        }
    }
    hits as f64 / total.max(1) as f64
}

/// The velocity source and its low-pass cut-off for `segments` (on the grid `dt`; `logged`: whether the log has a
/// velocity), as `asked` names them or as the logs' noise decides, with the reason. A logged velocity is a
/// measurement with noise of its own: differentiated as it is, white noise of `s` gives the acceleration noise of
/// `s sqrt(6) / dt`, so it is low-passed like the positions (zero-phase, the effort with it) at the cut-off its
/// noise allows, unless that is above any the log could use (a velocity measured cleanly). Where both could serve,
/// the one whose noise allows the higher cut-off (less of the motion smoothed away) is taken.
pub fn choose_signals(
    segments: &[&JointTrajectory],
    dt: f64,
    logged: bool,
    asked: &Conditioning,
) -> (VelocitySource, Option<f64>, String) {
    let (source, reason) = choose_velocity(segments[0], logged, asked.velocity);
    let positions = || asked.cutoff.unwrap_or_else(|| choose_cutoff(segments, dt));
    if source == VelocitySource::Positions {
        return (source, Some(positions()), reason);
    }
    if let Some(fc) = asked.cutoff {
        return (source, Some(fc), reason);
    }
    let Some(own) = velocity_cutoff(segments, dt) else {
        return (source, None, format!("{reason}; its noise is below what any cut-off would remove"));
    };
    let evidence = |fp: f64| format!("the logged velocity's noise allows {own:.1} Hz, the positions' {fp:.1} Hz");
    match asked.velocity {
        Some(_) => (source, Some(own), format!("{reason}; its noise allows {own:.1} Hz")),
        None => match positions() {
            fp if fp > own => (VelocitySource::Positions, Some(fp), evidence(fp)),
            fp => (source, Some(own), evidence(fp)),
        },
    }
}

/// The low-pass cut-off [Hz] at which the logged velocity's white noise leaves the acceleration within
/// [`ACCELERATION_NOISE`] of its own spread (the most noisy joint's), or `None` when that is above the highest
/// cut-off the log could use: white noise of variance `s^2` differentiated below `fc` has the variance
/// `(2 pi)^2 (2 s^2 / fs) fc^3 / 3`. The noise is measured as the effort's is ([`white_noise`]).
fn velocity_cutoff(segments: &[&JointTrajectory], dt: f64) -> Option<f64> {
    let fs = 1.0 / dt;
    let hi = (CUTOFF_SHARE * fs).min(CUTOFF_RANGE.1);
    let n = segments.first().map_or(0, |s| s.joints());
    let accs = acceleration_spread(segments, dt, (CUTOFF_RANGE.0 * 2.5).min(hi));
    let mut best = f64::INFINITY;
    for (j, &acc) in accs.iter().enumerate().take(n) {
        let Some(sigma) = white_noise(segments.iter().map(|s| (s.qd.as_slice(), s.len())), n, j) else { continue };
        if sigma <= 0.0 || acc <= 0.0 {
            continue;
        }
        let allowed = (ACCELERATION_NOISE * acc).powi(2);
        best = best.min((allowed * 3.0 * fs / ((2.0 * std::f64::consts::PI).powi(2) * 2.0 * sigma * sigma)).cbrt());
    }
    (best < hi).then(|| best.max(CUTOFF_RANGE.0))
}

/// The low-pass cut-off [Hz] for differentiating the positions of the segments (see the module documentation).
pub fn choose_cutoff(segments: &[&JointTrajectory], dt: f64) -> f64 {
    let fs = 1.0 / dt;
    let hi = (CUTOFF_SHARE * fs).min(CUTOFF_RANGE.1);
    let sigmas = position_noise(segments);
    // The acceleration's spread, seen through a filter low enough to hold no noise.
    let accs = acceleration_spread(segments, dt, (CUTOFF_RANGE.0 * 2.5).min(hi));
    let mut best = hi;
    for (&sigma, &acc) in sigmas.iter().zip(&accs) {
        if sigma <= 0.0 || acc <= 0.0 {
            continue;
        }
        // White position noise of variance s^2 has a one-sided PSD of 2 s^2 / fs; its second derivative below fc
        // has variance (2 pi)^4 (2 s^2 / fs) fc^5 / 5.
        let allowed = (ACCELERATION_NOISE * acc).powi(2);
        let fc = (allowed * 5.0 * fs / ((2.0 * std::f64::consts::PI).powi(4) * 2.0 * sigma * sigma)).powf(0.2);
        best = best.min(fc);
    }
    best.clamp(CUTOFF_RANGE.0, hi.max(CUTOFF_RANGE.0))
}

/// The standard deviation of each joint's position noise: a quantisation step's `step / sqrt(12)` when the positions
/// are quantised, else the white noise their third differences show (`var = 20 s^2`).
fn position_noise(segments: &[&JointTrajectory]) -> Vec<f64> {
    let n = segments.first().map_or(0, |s| s.joints());
    // Per joint: the sum of squared third differences and their count, the smallest step and the number of steps.
    let (mut sum3, mut count3) = (vec![0.0; n], 0usize);
    let (mut smallest, mut steps) = (vec![f64::INFINITY; n], vec![0usize; n]);
    for s in segments {
        for i in 1..s.len() {
            let (now, before) = (&s.q[i * n..(i + 1) * n], &s.q[(i - 1) * n..i * n]);
            for j in 0..n {
                let d = (now[j] - before[j]).abs();
                if d > 0.0 {
                    smallest[j] = smallest[j].min(d);
                    steps[j] += 1;
                }
            }
            if i >= 3 {
                let q = |back: usize, j: usize| s.q[(i - back) * n + j];
                for (j, sum) in sum3.iter_mut().enumerate() {
                    let d3 = q(0, j) - 3.0 * q(1, j) + 3.0 * q(2, j) - q(3, j);
                    *sum += d3 * d3;
                }
                count3 += 1;
            }
        }
    }
    // Quantised: every step a multiple of the smallest (to 1 %), which is then the encoder's resolution.
    let mut quantised: Vec<bool> = (0..n).map(|j| smallest[j].is_finite() && steps[j] > 100).collect();
    for s in segments {
        for i in 1..s.len() {
            for (j, q) in quantised.iter_mut().enumerate().filter(|(_, q)| **q) {
                let d = (s.q[i * n + j] - s.q[(i - 1) * n + j]).abs();
                let k = d / smallest[j];
                *q = d == 0.0 || (k - k.round()).abs() < 0.01;
            }
        }
    }
    (0..n)
        .map(|j| {
            let white = (sum3[j] / count3.max(1) as f64 / 20.0).sqrt();
            if quantised[j] { white.max(smallest[j] / 12f64.sqrt()) } else { white }
        })
        .collect()
}

/// Standard deviation of each joint's acceleration after a zero-phase low-pass at `fc`.
fn acceleration_spread(segments: &[&JointTrajectory], dt: f64, fc: f64) -> Vec<f64> {
    let n = segments.first().map_or(0, |s| s.joints());
    let (mut sum, mut sum2, mut count) = (vec![0.0; n], vec![0.0; n], 0usize);
    for s in segments {
        let f = Butterworth::new(fc, dt).filtfilt_columns(&s.q, n);
        for i in 1..s.len().saturating_sub(1) {
            for j in 0..n {
                let a = (f[(i + 1) * n + j] - 2.0 * f[i * n + j] + f[(i - 1) * n + j]) / (dt * dt);
                sum[j] += a;
                sum2[j] += a * a;
            }
            count += 1;
        }
    }
    let c = count.max(1) as f64;
    (0..n).map(|j| (sum2[j] / c - (sum[j] / c).powi(2)).max(0.0).sqrt()).collect()
}

/// A segment conditioned for identification: velocity from `source`, both effort pairings; low-passed at `cutoff`
/// (the positions always, a logged velocity when `cutoff` is finite).
pub fn condition(seg: &JointTrajectory, source: VelocitySource, cutoff: f64) -> Conditioned {
    let n = seg.joints();
    let len = seg.len();
    let dt = if len > 1 { (seg.t[len - 1] - seg.t[0]) / (len - 1) as f64 } else { 0.0 };
    let filtered = source == VelocitySource::Positions || cutoff < f64::MAX;
    let filter = Butterworth::new(cutoff, dt);
    // Row-major `[sample][joint]` throughout, as the log holds them: every joint filtered in one sweep.
    let tau = &seg.tau;
    let held = |i: usize, j: usize| if i > 0 { 0.5 * (tau[(i - 1) * n + j] + tau[i * n + j]) } else { tau[j] };
    let sampled = |i: usize, j: usize| match i > 0 && i + 1 < len {
        true => 0.25 * (tau[(i - 1) * n + j] + 2.0 * tau[i * n + j] + tau[(i + 1) * n + j]),
        false => tau[i * n + j],
    };
    let central = |x: &[f64], i: usize, j: usize| match i > 0 && i + 1 < len {
        true => (x[(i + 1) * n + j] - x[(i - 1) * n + j]) / (2.0 * dt),
        false => 0.0,
    };
    // (the filtered positions if any, qd, coulomb, [held, sampled]), each `[sample][joint]`.
    let (filtered_q, qd, coulomb, pairs) = match filtered {
        false => {
            let each = |f: &dyn Fn(usize, usize) -> f64| (0..len * n).map(|k| f(k / n, k % n)).collect::<Vec<f64>>();
            let coulomb = seg.qd.iter().map(|&v| sign(v)).collect();
            (None, seg.qd.clone(), coulomb, [each(&held), each(&sampled)])
        }
        true => {
            let q = filter.filtfilt_columns(&seg.q, n);
            let qd: Vec<f64> = match source {
                VelocitySource::Positions => (0..len * n).map(|k| central(&q, k / n, k % n)).collect(),
                VelocitySource::Logged => filter.filtfilt_columns(&seg.qd, n),
            };
            // The Coulomb column and both pairings through the same filter, side by side: `[sample][3 x joint]`. The
            // sampled pairing is the logged effort itself, the filter being zero-phase as the 1-2-1 average is; the
            // held one keeps its half-sample shift.
            let mut rows = Vec::with_capacity(3 * n * len);
            for i in 0..len {
                rows.extend((0..n).map(|j| sign(qd[i * n + j])));
                rows.extend((0..n).map(|j| held(i, j)));
                rows.extend_from_slice(&tau[i * n..(i + 1) * n]);
            }
            let rows = filter.filtfilt_columns(&rows, 3 * n);
            let part = |p: usize| -> Vec<f64> {
                rows.chunks_exact(3 * n).flat_map(|r| r[p * n..(p + 1) * n].iter().copied()).collect()
            };
            (Some(q), qd, part(0), [part(1), part(2)])
        }
    };
    let q = filtered_q.as_deref().unwrap_or(&seg.q);
    let mut out = Conditioned {
        joints: n,
        dt,
        q: seg.q.clone(),
        qd: vec![0.0; n * len],
        qdd: vec![0.0; n * len],
        v: vec![0.0; n * len],
        coulomb: vec![0.0; n * len],
        tau: [vec![0.0; n * len], vec![0.0; n * len]],
        rest_margin: match filtered {
            false => 0,
            true => (2.0 / (cutoff * dt)).ceil() as usize,
        },
    };
    for i in 1..len.saturating_sub(1) {
        for j in 0..n {
            let k = i * n + j;
            out.q[k] = q[k];
            out.qd[k] = qd[k];
            out.qdd[k] = match source {
                VelocitySource::Logged => central(&qd, i, j),
                VelocitySource::Positions => (q[k + n] - 2.0 * q[k] + q[k - n]) / (dt * dt),
            };
            out.v[k] = central(q, i, j);
            out.coulomb[k] = coulomb[k];
            out.tau[0][k] = pairs[0][k];
            out.tau[1][k] = pairs[1][k];
        }
    }
    out
}

/// The scatter of each joint's raw effort from sample to sample over `segments`, as a fraction of its spread: a
/// robust noise level that needs no model (see [`effort_noise`]). What a fit's residual is judged against: a residual
/// far above it is dynamics the model cannot take, not noise.
pub fn effort_scatter(segments: &[&JointTrajectory]) -> Vec<f64> {
    effort_noise(segments).into_iter().map(|(sigma, spread)| sigma / spread.max(f64::MIN_POSITIVE)).collect()
}

/// Each joint's white effort noise [N m or N] and its effort's standard deviation over `segments`: the noise is the
/// median absolute second difference over `0.6745 sqrt(6)`, which is white noise's standard deviation (a smooth
/// torque's second difference is `O(dt^2)` of its spread).
pub fn effort_noise(segments: &[&JointTrajectory]) -> Vec<(f64, f64)> {
    let n = segments.first().map_or(0, |s| s.joints());
    (0..n)
        .map(|j| {
            let Some(sigma) = white_noise(segments.iter().map(|s| (s.tau.as_slice(), s.len())), n, j) else {
                return (0.0, 0.0);
            };
            let (mut sum, mut sum2, mut count) = (0.0, 0.0, 0usize);
            for s in segments {
                for i in 0..s.len() {
                    let tau = s.tau[i * n + j];
                    sum += tau;
                    sum2 += tau * tau;
                    count += 1;
                }
            }
            let c = count as f64;
            (sigma, (sum2 / c - (sum / c).powi(2)).max(0.0).sqrt())
        })
        .collect()
}

/// The white noise of joint `j` of a signal (each segment's `[sample][joint]` values, `n` joints, and its length):
/// the median absolute second difference over `0.6745 sqrt(6)`, white noise's standard deviation (a smooth signal's
/// second difference is `O(dt^2)` of its spread); `None` without three samples in a segment.
fn white_noise<'a>(signals: impl Iterator<Item = (&'a [f64], usize)>, n: usize, j: usize) -> Option<f64> {
    let mut d2 = Vec::new();
    for (x, len) in signals {
        d2.extend((2..len).map(|i| (x[i * n + j] - 2.0 * x[(i - 1) * n + j] + x[(i - 2) * n + j]).abs()));
    }
    dynforge_recording::samples::median(&mut d2).map(|m| m / (0.6745 * 6f64.sqrt()))
}

/// The factor by which conditioning scales white effort noise (its standard deviation): the pairing's average of
/// neighbouring efforts, and the filter's noise bandwidth when the signals are low-passed.
pub fn noise_gain(source: VelocitySource, cutoff: Option<f64>, convention: EffortConvention, dt: f64) -> f64 {
    let pairing = match convention {
        EffortConvention::Held => 0.5f64.sqrt(),
        EffortConvention::Sampled => (6.0f64 / 16.0).sqrt(),
    };
    match (source, cutoff) {
        (_, Some(fc)) => {
            let f = Butterworth::new(fc, dt);
            let len = 2 * f.pad + 1;
            let mut impulse = vec![0.0; len];
            impulse[len / 2] = 1.0;
            let response = f.filtfilt(&impulse);
            pairing * response.iter().map(|v| v * v).sum::<f64>().sqrt()
        }
        _ => pairing,
    }
}

/// A 4th-order Butterworth low-pass as two biquad sections, run forward then backward (zero phase, the magnitude
/// squared). The ends are padded by odd reflection over a few periods of the cut-off, so the filter starts and ends
/// on the signal's own trend instead of a step.
#[derive(Debug, Clone, Copy)]
pub struct Butterworth {
    sections: [[f64; 5]; 2],
    pad: usize,
}

impl Butterworth {
    pub fn new(cutoff: f64, dt: f64) -> Self {
        let k = (std::f64::consts::PI * cutoff * dt).tan();
        let section = |q: f64| {
            let norm = 1.0 / (1.0 + k / q + k * k);
            let b0 = k * k * norm;
            [b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm]
        };
        // The poles of the 4th-order Butterworth: Q = 1 / (2 cos(pi/8)) and 1 / (2 cos(3 pi/8)).
        let q1 = 1.0 / (2.0 * (std::f64::consts::PI / 8.0).cos());
        let q2 = 1.0 / (2.0 * (3.0 * std::f64::consts::PI / 8.0).cos());
        // Ten periods of the cut-off: the slowest pole (decay 2 pi fc cos(3 pi / 8)) forgets the start by e^-24.
        let pad = ((10.0 / (cutoff * dt)).ceil() as usize).max(12);
        Butterworth { sections: [section(q1), section(q2)], pad }
    }

    /// `x` filtered forward and backward. A line passes unchanged once the start has been forgotten (see `new`): the
    /// odd reflection continues a linear trend across the ends.
    pub fn filtfilt(&self, x: &[f64]) -> Vec<f64> {
        self.filtfilt_columns(x, 1)
    }

    /// [`Self::filtfilt`] of each of the `channels` signals interleaved in `x` (sample `i` of signal `c` at
    /// `x[i * channels + c]`, the layout of a log's joints), in that layout. One sweep takes every signal and both
    /// sections: their recursions are independent, so the core overlaps them instead of waiting on each in turn (an
    /// hour's log is filtered tens of times over).
    pub fn filtfilt_columns(&self, x: &[f64], channels: usize) -> Vec<f64> {
        let len = x.len() / channels.max(1);
        if len < 3 {
            return x.to_vec();
        }
        let pad = self.pad.min(len - 1);
        let at = |i: usize| &x[i * channels..(i + 1) * channels];
        let mut y = Vec::with_capacity((len + 2 * pad) * channels);
        for i in (1..=pad).rev() {
            y.extend(at(0).iter().zip(at(i)).map(|(a, b)| 2.0 * a - b));
        }
        y.extend_from_slice(x);
        for i in 1..=pad {
            y.extend(at(len - 1).iter().zip(at(len - 1 - i)).map(|(a, b)| 2.0 * a - b));
        }
        self.sweep(&mut y, channels, false);
        self.sweep(&mut y, channels, true);
        y.drain(..pad * channels);
        y.truncate(len * channels);
        y
    }

    /// Both sections over the rows of `y` (`channels` signals interleaved), first to last or last to first. Each
    /// section starts in the steady state of its first input, so a constant passes unchanged.
    fn sweep(&self, y: &mut [f64], channels: usize, backward: bool) {
        let rows = y.len() / channels;
        let [s, t] = self.sections;
        let steady = |[b0, b1, b2, a1, a2]: [f64; 5], x0: f64| x0 * (b0 + b1 + b2) / (1.0 + a1 + a2);
        // (x[i-1], x[i-2], y[i-1], y[i-2]) of a section, updated by its input `v`; its output.
        let step = |[b0, b1, b2, a1, a2]: [f64; 5], st: &mut [f64; 4], v: f64| {
            let [x1, x2, y1, y2] = *st;
            let out = b0 * v + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
            *st = [v, x1, out, y1];
            out
        };
        let row = |i: usize| if backward { rows - 1 - i } else { i };
        let first = row(0) * channels;
        let mut states: Vec<([f64; 4], [f64; 4])> = y[first..first + channels]
            .iter_mut()
            .map(|v| {
                let u0 = steady(s, *v);
                let mut a = [*v, *v, u0, u0];
                let mid = step(s, &mut a, *v);
                let w0 = steady(t, mid);
                let mut b = [mid, mid, w0, w0];
                *v = step(t, &mut b, mid);
                (a, b)
            })
            .collect();
        for i in 1..rows {
            let r = row(i) * channels;
            for (v, (a, b)) in y[r..r + channels].iter_mut().zip(&mut states) {
                let mid = step(s, a, *v);
                *v = step(t, b, mid);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_filter_passes_slow_motion_and_stops_fast_noise_without_phase() {
        let dt = 1e-3;
        let f = Butterworth::new(20.0, dt);
        let n = 4000;
        let slow: Vec<f64> = (0..n).map(|i| (2.0 * std::f64::consts::PI * 1.0 * i as f64 * dt).sin()).collect();
        let fast: Vec<f64> = (0..n).map(|i| (2.0 * std::f64::consts::PI * 200.0 * i as f64 * dt).sin()).collect();
        // |H(f)|^2 of a 4th-order Butterworth at f / fc = 0.05: 1 - 0.05^8 / 2 (amplitude through both passes).
        let ys = f.filtfilt(&slow);
        let err = ys.iter().zip(&slow).skip(500).take(n - 1000).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-6, "slow motion changed by {err}");
        // At f / fc = 10: |H|^2 = 1 / (1 + 10^8) per pass pair.
        let yf = f.filtfilt(&fast);
        let amp = yf.iter().skip(500).take(n - 1000).fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(amp < 1e-6, "fast noise left {amp}");
        // A line passes unchanged, ends included (odd reflection continues it).
        let line: Vec<f64> = (0..2000).map(|i| 3.0 + 0.01 * i as f64).collect();
        let yl = f.filtfilt(&line);
        let err = yl.iter().zip(&line).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        assert!(err < 1e-8, "a line changed by {err}");
    }

    #[test]
    fn signals_filtered_side_by_side_are_each_filtered_alone() {
        // Interleaved, as a log's joints are: every signal to the last bit as if it were alone, the ends included.
        let f = Butterworth::new(15.0, 1e-3);
        let signals: Vec<Vec<f64>> = (0..3)
            .map(|c| {
                (0..700).map(|i| ((i * (c + 3)) as f64 * 0.01).sin() + if i % 7 == c { 0.1 } else { 0.0 }).collect()
            })
            .collect();
        let rows: Vec<f64> = (0..700).flat_map(|i| signals.iter().map(move |s| s[i])).collect();
        let together = f.filtfilt_columns(&rows, 3);
        for (c, s) in signals.iter().enumerate() {
            let alone = f.filtfilt(s);
            assert!(together.iter().skip(c).step_by(3).zip(&alone).all(|(a, b)| a.to_bits() == b.to_bits()), "{c}");
        }
    }

    #[test]
    fn the_cutoff_follows_the_encoder_resolution() {
        let dt = 1e-3;
        let n = 20_000;
        let counts = |c: f64| {
            let step = 2.0 * std::f64::consts::PI / c;
            let q: Vec<f64> = (0..n)
                .map(|i| {
                    let t = i as f64 * dt;
                    let v = 0.8 * (2.0 * std::f64::consts::PI * 0.3 * t).sin()
                        + 0.3 * (2.0 * std::f64::consts::PI * 0.7 * t).cos();
                    (v / step).round() * step
                })
                .collect();
            JointTrajectory {
                names: vec!["j".into()],
                t: (0..n).map(|i| i as f64 * dt).collect(),
                q,
                qd: vec![0.0; n],
                tau: vec![0.0; n],
            }
        };
        let fine = choose_cutoff(&[&counts((1u64 << 20) as f64)], dt);
        let coarse = choose_cutoff(&[&counts((1u64 << 14) as f64)], dt);
        // Coarser steps are noisier: a lower cut-off, by the fifth root of the noise power ratio (2^12 -> 5.3x).
        let ratio = 2f64.powf(12.0 / 5.0);
        assert!((fine / coarse - ratio).abs() < 0.1 * ratio, "{fine} {coarse}");
        assert!((CUTOFF_RANGE.0..=250.0).contains(&coarse));
    }
}
