//! Joint trajectories from shards and ROS 2 bags, with joints matched by name to the robot model's order.

use std::path::Path;

use dynforge_proto::shard::JointState;
use dynforge_shard::Bag;

/// A stamp this many median periods after the previous one starts a new segment; smaller gaps (a dropped message)
/// are interpolated over.
pub const GAP_PERIODS: f64 = 5.0;

/// Samples of a robot's joints: row-major `[t][joint]` arrays in the model's joint order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct JointTrajectory {
    /// Joint names, in the model's order.
    pub names: Vec<String>,
    /// Sample times [s], strictly increasing.
    pub t: Vec<f64>,
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub tau: Vec<f64>,
}

impl JointTrajectory {
    pub fn joints(&self) -> usize {
        self.names.len()
    }

    /// Sample `i`'s positions, velocities and torques.
    pub fn sample(&self, i: usize) -> (&[f64], &[f64], &[f64]) {
        let r = i * self.joints()..(i + 1) * self.joints();
        (&self.q[r.clone()], &self.qd[r.clone()], &self.tau[r])
    }

    /// Samples `range` as a trajectory of their own.
    pub fn slice(&self, range: std::ops::Range<usize>) -> JointTrajectory {
        let n = self.joints();
        let rows = range.start * n..range.end * n;
        JointTrajectory {
            names: self.names.clone(),
            t: self.t[range].to_vec(),
            q: self.q[rows.clone()].to_vec(),
            qd: self.qd[rows.clone()].to_vec(),
            tau: self.tau[rows].to_vec(),
        }
    }

    pub fn len(&self) -> usize {
        self.t.len()
    }
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct SamplesError {
    pub file: String,
    pub problem: String,
}

/// The `/joint_states` of `bag` for the joints `names` (in that order), matched by name in every message. Messages
/// must carry position, velocity and effort for each of these joints; other joints are ignored. Samples are sorted
/// by stamp; repeated stamps keep the first message; times count from the first stamp.
pub fn from_bag(bag: &Bag, names: &[String], file: &Path) -> Result<JointTrajectory, SamplesError> {
    Ok(joint_states(bag, names, file, true)?.0)
}

/// [`from_bag`] for a log whose driver may publish no velocity: when no message has any (empty `velocity`
/// arrays, as ROS 2 allows), the velocities are zeros and the flag says they were not logged.
pub fn from_bag_any_velocity(
    bag: &Bag,
    names: &[String],
    file: &Path,
) -> Result<(JointTrajectory, bool), SamplesError> {
    let logged = bag.joint_states.iter().any(|m| !m.velocity.is_empty());
    joint_states(bag, names, file, logged)
}

fn joint_states(
    bag: &Bag,
    names: &[String],
    file: &Path,
    with_velocity: bool,
) -> Result<(JointTrajectory, bool), SamplesError> {
    let err = |problem: String| SamplesError { file: file.display().to_string(), problem };
    if bag.joint_states.is_empty() {
        return Err(err("no sensor_msgs/msg/JointState messages on /joint_states".into()));
    }
    let n = names.len();
    // Stamps, and position, velocity and effort of each message in the model's joint order, as flat columns (an
    // hour's log holds millions of messages: no allocation per message), a stretch of messages per core.
    let messages = bag.joint_states.len();
    let (mut stamps, mut q, mut qd, mut tau) =
        (vec![0; messages], vec![0.0; messages * n], vec![0.0; messages * n], vec![0.0; messages * n]);
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    let per = messages.div_ceil(threads).max(1);
    let results: Vec<Result<(), MessageProblem>> = std::thread::scope(|scope| {
        let stretches = bag.joint_states.chunks(per).zip(stamps.chunks_mut(per));
        let columns = q.chunks_mut(per * n).zip(qd.chunks_mut(per * n)).zip(tau.chunks_mut(per * n));
        let handles: Vec<_> = stretches
            .zip(columns)
            .enumerate()
            .map(|(i, ((msgs, stamps), ((q, qd), tau)))| {
                let out = Columns { stamps, q, qd: with_velocity.then_some(qd), tau };
                scope.spawn(move || pick_columns(msgs, i * per, names, out))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    });
    // The first stretch's error is the first message's that has one.
    if let Some(problem) = results.into_iter().find_map(Result::err) {
        return Err(err(problem.to_string()));
    }
    // In stamp order (stable: a repeated stamp keeps its first message).
    let mut order: Vec<usize> = (0..messages).collect();
    if !stamps.is_sorted() {
        order.sort_by_key(|&k| stamps[k]);
    }
    order.dedup_by_key(|k| stamps[*k]);
    // A republished message repeats a stamp now and then; a driver that does not stamp repeats one throughout.
    let repeated = messages - order.len();
    if repeated > 1 + messages / 100 {
        return Err(err(format!(
            "{repeated} of {messages} joint_states messages repeat an earlier header stamp ({} distinct, the first \
             {:.6} s): the log's stamps do not tell when its samples were taken; record it with stamped messages",
            order.len(),
            stamps[order[0]] as f64 * 1e-9
        )));
    }
    let mut out = JointTrajectory { names: names.to_vec(), ..JointTrajectory::default() };
    // Times from the first stamp, in exact nanoseconds before the conversion: a stamp of 1.7e9 s (a real clock)
    // converted whole would carry 2.4e-7 s of rounding into every period.
    let first = order.first().map_or(0, |&k| stamps[k]);
    out.t = order.iter().map(|&k| (stamps[k] - first) as f64 * 1e-9).collect();
    if order.len() == messages && order.iter().enumerate().all(|(i, &k)| i == k) {
        // Already in order (what a recorder writes): the columns as they are, no copy of an hour's log.
        (out.q, out.qd, out.tau) = (q, qd, tau);
    } else {
        let pick = |column: &[f64]| order.iter().flat_map(|&k| column[k * n..(k + 1) * n].iter().copied()).collect();
        (out.q, out.qd, out.tau) = (pick(&q), pick(&qd), pick(&tau));
    }
    Ok((out, with_velocity))
}

/// Why a joint_states message gives no sample of the robot's joints.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum MessageProblem {
    #[error("joint_states message {message} has no joint '{joint}' (it has {has:?})")]
    NoJoint { message: usize, joint: String, has: Vec<String> },
    #[error("joint_states message {message}: {values} {what} values for {joints} joints")]
    Values { message: usize, values: usize, what: &'static str, joints: usize },
    #[error(
        "joint_states message {message} (t = {t:.6} s): {what} of joint '{joint}' is {value} (dynforge needs \
         measured position, velocity and effort for every joint)"
    )]
    NotFinite { message: usize, t: f64, what: &'static str, joint: String, value: f64 },
}

/// Where [`pick_columns`] writes a stretch of messages: their stamps [ns] and `[message][joint]` values (no
/// velocity when the log has none).
struct Columns<'a> {
    stamps: &'a mut [i64],
    q: &'a mut [f64],
    qd: Option<&'a mut [f64]>,
    tau: &'a mut [f64],
}

/// The stamps and the joints `names`' values of `messages` (the log's from message `first` on) into `out`; the
/// first message's problem if one has none.
fn pick_columns(
    messages: &[JointState],
    first: usize,
    names: &[String],
    mut out: Columns,
) -> Result<(), MessageProblem> {
    let n = names.len();
    let mut columns: Vec<usize> = Vec::with_capacity(n);
    let mut last_layout: Option<&std::sync::Arc<[String]>> = None;
    for (i, m) in messages.iter().enumerate() {
        let k = first + i;
        // Messages that name the same joints share one list (the decoder's): a pointer says so without a comparison.
        if !last_layout.is_some_and(|last| std::sync::Arc::ptr_eq(last, &m.name) || **last == *m.name) {
            columns.clear();
            for want in names {
                let c = m.name.iter().position(|have| have == want).ok_or_else(|| MessageProblem::NoJoint {
                    message: k,
                    joint: want.clone(),
                    has: m.name.to_vec(),
                })?;
                columns.push(c);
            }
            last_layout = Some(&m.name);
        }
        let pick = |v: &[f64], what: &'static str, out: &mut [f64]| -> Result<(), MessageProblem> {
            if v.len() != m.name.len() {
                return Err(MessageProblem::Values { message: k, values: v.len(), what, joints: m.name.len() });
            }
            // Drivers that do not measure a quantity often publish NaN for it; nothing downstream can use a
            // non-finite sample, and silently dropping it would bias the log.
            if let Some((&c, want)) = columns.iter().zip(names).find(|&(&c, _)| !v[c].is_finite()) {
                let t = m.stamp_ns() as f64 * 1e-9;
                return Err(MessageProblem::NotFinite { message: k, t, what, joint: want.clone(), value: v[c] });
            }
            out.iter_mut().zip(&columns).for_each(|(o, &c)| *o = v[c]);
            Ok(())
        };
        let at = i * n..(i + 1) * n;
        if let Some(qd) = out.qd.as_deref_mut() {
            pick(&m.velocity, "velocity", &mut qd[at.clone()])?;
        }
        pick(&m.position, "position", &mut out.q[at.clone()])?;
        pick(&m.effort, "effort", &mut out.tau[at])?;
        out.stamps[i] = m.stamp_ns();
    }
    Ok(())
}

/// What a logger's clock did: samples that repeat the one before with a new stamp (a logger stamping by its own
/// thread, not the driver's), and steps of about two or more periods (a tick it missed), short of a gap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Clock {
    pub repeats: usize,
    pub skipped: usize,
}

impl JointTrajectory {
    /// What the logger's clock did ([`Clock`]), with its stale repeats left out (`drop_repeats`). The missed
    /// ticks are counted on the stamps as logged, before: a repeat left out leaves a step of two periods too.
    pub fn clock(&mut self) -> Clock {
        let mut steps: Vec<f64> = self.t.windows(2).map(|w| w[1] - w[0]).collect();
        let skipped = median(&mut steps).map_or(0, |period| {
            let ticks = |s: f64| s >= MISSED_TICK * period && s <= GAP_PERIODS * period;
            self.t.windows(2).filter(|w| ticks(w[1] - w[0])).count()
        });
        Clock { repeats: self.drop_repeats(), skipped }
    }

    /// Leaves out the samples that repeat the one before exactly (every position, velocity and effort) while the arm
    /// moves (a logged velocity that is not zero, or positions that changed the step before): an arm in motion does
    /// not measure the same values twice, and such a sample is a logger's stale copy. Returns how many.
    fn drop_repeats(&mut self) -> usize {
        let n = self.joints();
        let keep: Vec<bool> = (0..self.len())
            .map(|k| {
                if k == 0 {
                    return true;
                }
                let same = |v: &[f64]| v[k * n..(k + 1) * n] == v[(k - 1) * n..k * n];
                let moving = self.qd[(k - 1) * n..k * n].iter().any(|&v| v != 0.0)
                    || (k >= 2 && self.q[(k - 1) * n..k * n] != self.q[(k - 2) * n..(k - 1) * n]);
                !(same(&self.q) && same(&self.qd) && same(&self.tau) && moving)
            })
            .collect();
        let dropped = keep.iter().filter(|k| !**k).count();
        if dropped > 0 {
            let kept = |v: &[f64]| -> Vec<f64> {
                let mut out = Vec::with_capacity(v.len() - dropped * n);
                (0..keep.len()).filter(|&k| keep[k]).for_each(|k| out.extend_from_slice(&v[k * n..(k + 1) * n]));
                out
            };
            (self.q, self.qd, self.tau) = (kept(&self.q), kept(&self.qd), kept(&self.tau));
            self.t = self.t.iter().zip(&keep).filter(|(_, k)| **k).map(|(t, _)| *t).collect();
        }
        dropped
    }
}

/// A step of this many median periods or more (and up to a gap) is a tick the logger missed: two periods and
/// more, where a driver's jitter stays well below.
pub const MISSED_TICK: f64 = 1.8;

/// The median of `values` (the upper one of an even count: the element a sort would put at `len / 2`), found by
/// selection in linear time; `values` is reordered. `None` when empty. Logs of an hour hold millions of steps and
/// differences, where a sort per median was a measurable share of reading them.
pub fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let half = values.len() / 2;
    let (_, &mut m, _) = values.select_nth_unstable_by(half, f64::total_cmp);
    Some(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dynforge_proto::shard::JointState;

    fn message(t_ns: i64, names: &[&str], base: f64) -> JointState {
        let idx = |n: &str| n.strip_prefix("j").and_then(|i| i.parse::<f64>().ok()).unwrap_or(99.0);
        JointState {
            sec: (t_ns / 1_000_000_000) as i32,
            nanosec: (t_ns % 1_000_000_000) as u32,
            frame_id: String::new(),
            name: names.iter().map(|n| n.to_string()).collect(),
            position: names.iter().map(|n| base + idx(n)).collect(),
            velocity: names.iter().map(|n| 10.0 * idx(n)).collect(),
            effort: names.iter().map(|n| -idx(n)).collect(),
        }
    }

    #[test]
    fn joints_are_matched_by_name_and_samples_sorted_by_stamp() {
        let names: Vec<String> = ["j0", "j1", "j2"].iter().map(|s| s.to_string()).collect();
        let bag = Bag {
            joint_states: vec![
                message(2_000_000, &["j2", "j0", "j1", "gripper"], 0.2),
                message(0, &["j0", "j1", "j2"], 0.0),
                message(1_000_000, &["j1", "j2", "j0"], 0.1),
                message(1_000_000, &["j1", "j2", "j0"], 9.9),
            ],
            ..Bag::default()
        };
        let t = from_bag(&bag, &names, Path::new("rec.mcap")).unwrap();
        assert_eq!(t.t, [0.0, 0.001, 0.002]);
        for k in 0..3 {
            let base = [0.0, 0.1, 0.2][k];
            assert_eq!(&t.q[3 * k..3 * k + 3], &[base, base + 1.0, base + 2.0]);
            assert_eq!(&t.qd[3 * k..3 * k + 3], &[0.0, 10.0, 20.0]);
            assert_eq!(&t.tau[3 * k..3 * k + 3], &[0.0, -1.0, -2.0]);
        }
    }

    #[test]
    fn missing_joints_or_empty_bags_are_errors_naming_the_file() {
        let names: Vec<String> = ["j0", "j7"].iter().map(|s| s.to_string()).collect();
        let bag = Bag { joint_states: vec![message(0, &["j0", "j1"], 0.0)], ..Bag::default() };
        let e = from_bag(&bag, &names, Path::new("robot.mcap")).unwrap_err().to_string();
        assert!(e.starts_with("robot.mcap: ") && e.contains("no joint 'j7'"), "{e}");
        let e = from_bag(&Bag::default(), &names, Path::new("robot.mcap")).unwrap_err().to_string();
        assert!(e.contains("no sensor_msgs/msg/JointState"), "{e}");
        let mut unmeasured = message(3_000_000, &["j0", "j7"], 0.0);
        unmeasured.effort[1] = f64::NAN;
        let bag = Bag { joint_states: vec![unmeasured], ..Bag::default() };
        let e = from_bag(&bag, &names, Path::new("robot.mcap")).unwrap_err().to_string();
        assert!(
            e.starts_with("robot.mcap: ") && e.contains("effort of joint 'j7' is NaN") && e.contains("0.003"),
            "{e}"
        );
        let mut short = message(0, &["j0", "j7"], 0.0);
        short.effort.pop();
        let e =
            from_bag(&Bag { joint_states: vec![short], ..Bag::default() }, &names, Path::new("r.mcap")).unwrap_err();
        assert!(e.to_string().contains("1 effort values for 2 joints"), "{e}");
        // Read a stretch per core, the first message with a problem is the one named.
        let mut log: Vec<JointState> = (0..9).map(|k| message(k * 1_000_000, &["j0", "j7"], 0.0)).collect();
        log[8].position[0] = f64::INFINITY;
        log[2].position[1] = f64::NAN;
        let e = from_bag(&Bag { joint_states: log, ..Bag::default() }, &names, Path::new("r.mcap")).unwrap_err();
        assert!(e.to_string().contains("message 2 (t = 0.002000 s): position of joint 'j7' is NaN"), "{e}");
    }

    #[test]
    fn a_log_without_stamps_is_refused_instead_of_shrinking_to_one_sample() {
        let names: Vec<String> = ["j0"].iter().map(|s| s.to_string()).collect();
        let bag = Bag { joint_states: (0..8001).map(|k| message(0, &["j0"], k as f64)).collect(), ..Bag::default() };
        let e = from_bag(&bag, &names, Path::new("unstamped.mcap")).unwrap_err().to_string();
        assert!(e.starts_with("unstamped.mcap: 8000 of 8001 joint_states messages repeat"), "{e}");
    }

    #[test]
    fn a_logger_s_stale_repeats_are_left_out_and_its_missed_ticks_counted() {
        let rows = [
            (0.000, 0.0, 0.0, 1.0),
            (0.001, 0.0, 0.0, 1.0), // at rest: the same values are a measurement, kept
            (0.002, 0.1, 1.0, 2.0),
            (0.003, 0.1, 1.0, 2.0), // moving: a stale copy
            (0.004, 0.3, 1.0, 2.5),
            (0.006, 0.5, 1.0, 2.6), // a missed tick
            (0.007, 0.6, 1.0, 2.6), // the effort alone repeats: kept
            (0.008, 0.7, 1.0, 2.7),
            (0.018, 0.8, 1.0, 2.8), // a gap, not a missed tick
        ];
        let mut traj = JointTrajectory {
            names: vec!["j".into()],
            t: rows.iter().map(|r| r.0).collect(),
            q: rows.iter().map(|r| r.1).collect(),
            qd: rows.iter().map(|r| r.2).collect(),
            tau: rows.iter().map(|r| r.3).collect(),
        };
        let mut unlogged = traj.clone();
        assert_eq!(traj.clock(), Clock { repeats: 1, skipped: 1 });
        assert_eq!(traj.t, [0.000, 0.001, 0.002, 0.004, 0.006, 0.007, 0.008, 0.018]);
        assert_eq!(traj.q, [0.0, 0.0, 0.1, 0.3, 0.5, 0.6, 0.7, 0.8]);
        assert_eq!(traj.tau, [1.0, 1.0, 2.0, 2.5, 2.6, 2.6, 2.7, 2.8]);
        // Without a logged velocity, motion shows in the positions' step before.
        unlogged.qd.iter_mut().for_each(|v| *v = 0.0);
        assert_eq!(unlogged.clock(), Clock { repeats: 1, skipped: 1 });
        assert_eq!(unlogged.q, traj.q);
    }

    #[test]
    fn the_median_is_the_element_a_sort_puts_at_half_the_length() {
        assert_eq!(median(&mut []), None);
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(3.0));
        let mut rng = dynforge_robot::rng::Rng::stream(5, &[]);
        let values: Vec<f64> = (0..1001).map(|_| rng.normal()).collect();
        let mut sorted = values.clone();
        sorted.sort_by(f64::total_cmp);
        assert_eq!(median(&mut values.clone()), Some(sorted[500]));
    }
}
