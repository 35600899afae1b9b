//! Whether logs ran the designed excitations: `calibrate` measures its spreads on a family simulated running those
//! excitations, which says nothing of a log of some other motion. Each excitation is looked for in every log, at
//! every start, by its joints' positions.

use dynforge_proto::family::excitation_file;
use dynforge_proto::fourier::Excitation;
use dynforge_recording::log::Log;

use super::CalibrateError;

/// Largest RMS difference between a log's positions and an excitation's, as a share of the excitation's motion (RMS
/// about its start pose), at which the log is taken to have run it. A stiff controller tracks a designed excitation
/// to a few percent of it; the tests' MuJoCo UR5, under a 20 rad/s loop that does not feed its friction forward, lags
/// by 21 % (its wrist by 0.1 rad); another motion of the same size is off by about 140 % (two independent motions:
/// sqrt(2) of their size), and the excitation found 20 ms from its true start by 2-4 % more at a UR's speeds.
pub const RAN_TOLERANCE: f64 = 0.5;

/// Spacing of the samples compared, and of the starts tried [s].
const STEP: f64 = 0.02;

/// Where a log ran an excitation.
#[derive(Debug, Clone, PartialEq)]
pub struct Ran {
    /// The log's name and the excitation's index.
    pub log: String,
    pub excitation: usize,
    /// Seconds from the log's first sample to the excitation's start.
    pub start: f64,
    /// RMS position difference over the excitation's motion ([`RAN_TOLERANCE`]).
    pub error: f64,
}

impl Ran {
    /// How close the nearest match came, for a refusal.
    fn closest(&self) -> String {
        match self.error.is_finite() {
            true => format!(
                "the closest is {} in {} from {:.2} s, off by {:.0} % of its motion",
                excitation_file(self.excitation),
                self.log,
                self.start,
                100.0 * self.error
            ),
            false => format!("{} has no stretch as long as {}", self.log, excitation_file(self.excitation)),
        }
    }
}

impl std::fmt::Display for Ran {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: ran {} from {:.2} s (positions off by {:.1} % of its motion; at most {:.0} % taken)",
            self.log,
            excitation_file(self.excitation),
            self.start,
            100.0 * self.error,
            100.0 * RAN_TOLERANCE
        )
    }
}

/// Where each of `logs` ran one of `excitations` (in the logs' order), or an error naming the log that ran none,
/// or the excitation no log ran, with the closest match.
pub fn check_ran(logs: &[Log], excitations: &[Excitation]) -> Result<Vec<Ran>, CalibrateError> {
    let mut best: Vec<Vec<Ran>> = Vec::with_capacity(logs.len());
    for log in logs {
        let row = (excitations.iter().enumerate()).map(|(k, e)| closest(log, k, e)).collect::<Result<Vec<_>, _>>()?;
        best.push(row);
    }
    let within = |r: &Ran| r.error <= RAN_TOLERANCE;
    for k in 0..excitations.len() {
        let nearest = best.iter().map(|row| &row[k]).min_by(|a, b| a.error.total_cmp(&b.error));
        match nearest {
            Some(r) if within(r) => {}
            nearest => {
                return Err(CalibrateError::NotRun(format!(
                    "no log ran {}{}: give a log of the arm running every excitation of the set",
                    excitation_file(k),
                    nearest.map_or(String::new(), |r| format!(" ({})", r.closest()))
                )));
            }
        }
    }
    let mut ran = Vec::with_capacity(logs.len());
    for row in best {
        let nearest = row.into_iter().min_by(|a, b| a.error.total_cmp(&b.error)).expect("an excitation at least");
        if !within(&nearest) {
            return Err(CalibrateError::NotRun(format!(
                "{}: ran none of the excitations ({}): the family's spreads are of the designed motions only, so every \
                 log must run one",
                nearest.log,
                nearest.closest()
            )));
        }
        ran.push(nearest);
    }
    Ok(ran)
}

/// The start in `log` where its positions come closest to excitation `k` (`e`), over every segment long enough.
fn closest(log: &Log, k: usize, e: &Excitation) -> Result<Ran, CalibrateError> {
    let names: Vec<&str> = log.model.joints().iter().map(|j| j.name.as_str()).collect();
    let columns = (e.joints.iter())
        .map(|name| {
            names.iter().position(|n| n == name).ok_or_else(|| {
                CalibrateError::NotRun(format!(
                    "{}: the log has no joint '{name}', which {} moves (its joints: {})",
                    log.name(),
                    excitation_file(k),
                    names.join(", ")
                ))
            })
        })
        .collect::<Result<Vec<usize>, _>>()?;
    let s = &e.series;
    let m = (s.period / STEP).floor() as usize;
    let (mut q, mut qd, mut qdd) = (vec![0.0; columns.len()], vec![0.0; columns.len()], vec![0.0; columns.len()]);
    let mut designed = Vec::with_capacity((m + 1) * columns.len());
    for i in 0..=m {
        s.at(i as f64 * STEP, &mut q, &mut qd, &mut qdd);
        designed.extend_from_slice(&q);
    }
    let size = (designed.chunks(columns.len()))
        .flat_map(|row| row.iter().zip(&s.start).map(|(q, q0)| (q - q0).powi(2)))
        .sum::<f64>()
        / designed.len() as f64;
    let size = size.sqrt().max(f64::MIN_POSITIVE);
    let n = names.len();
    let mut best = Ran { log: log.name(), excitation: k, start: 0.0, error: f64::INFINITY };
    let first = log.segments.first().map_or(0.0, |seg| seg.t[0]);
    for seg in &log.segments {
        let span = seg.t.last().copied().unwrap_or(0.0) - seg.t[0];
        if span + 0.5 * log.dt < m as f64 * STEP {
            continue;
        }
        let at = |t: f64| ((t / log.dt).round() as usize).min(seg.t.len() - 1);
        let starts = ((span - m as f64 * STEP) / STEP).floor().max(0.0) as usize;
        for o in 0..=starts {
            let mut sum = 0.0;
            for (i, row) in designed.chunks(columns.len()).enumerate() {
                let sample = at((o + i) as f64 * STEP);
                sum += columns.iter().zip(row).map(|(&c, d)| (seg.q[sample * n + c] - d).powi(2)).sum::<f64>();
            }
            let error = (sum / designed.len() as f64).sqrt() / size;
            if error < best.error {
                best = Ran { start: seg.t[0] - first + o as f64 * STEP, error, ..best };
            }
        }
    }
    Ok(best)
}
