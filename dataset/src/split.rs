//! Train/validation splits, deterministic from a seed. By robot (the default): no validation robot is ever seen in
//! training, which is what a user's new robot is. By trajectory or by window: validation data come from robots seen
//! in training with other recordings or other windows, the protocols a paper may have used without saying so
//! (a network that recognises a robot by its kinematics can recall its parameters there).

use crate::window::WindowSpec;
use dynforge_proto::content_hash;

/// Which side of the split a sample belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Split {
    Train,
    Validation,
}

/// Robot `robot` goes to validation with probability `fraction`, decided by a hash of `(seed, robot)` alone: the
/// same on every machine and in every process, whatever order the shards arrive in.
pub fn split_of(seed: u64, robot: u64, fraction: f64) -> Split {
    let mut key = [0u8; 16];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..].copy_from_slice(&robot.to_le_bytes());
    let u = (content_hash(&key) >> 11) as f64 / (1u64 << 53) as f64;
    if u < fraction { Split::Validation } else { Split::Train }
}

/// What a split holds out for validation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HoldOut {
    /// Whole robots.
    #[default]
    Robots,
    /// Whole recordings, of robots whose other recordings are trained on.
    Trajectories,
    /// Time segments of recordings drawn across all robots and recordings: a window and its offset siblings (the same
    /// stretch of motion shifted by a few milliseconds) are on one side.
    Windows,
}

impl HoldOut {
    pub fn name(self) -> &'static str {
        match self {
            HoldOut::Robots => "robots",
            HoldOut::Trajectories => "trajectories",
            HoldOut::Windows => "windows",
        }
    }
}

/// Where a window comes from: its robot, the recording (the robot's trajectory index) and its time segment in the
/// recording (see [`segments`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Origin {
    pub robot: u64,
    pub trajectory: u32,
    pub segment: u32,
}

/// A train/validation split: what is held out, the seed and the share held out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitRule {
    pub by: HoldOut,
    pub seed: u64,
    pub fraction: f64,
}

impl SplitRule {
    /// The split by robot of `seed` (the training runs' default).
    pub fn robots(seed: u64, fraction: f64) -> Self {
        SplitRule { by: HoldOut::Robots, seed, fraction }
    }

    /// The side of the window at `o`: decided by a hash of the seed and of what is held out (the robot; the robot and
    /// trajectory; or those and the time segment), so every window of a held-out unit is on the same side, on every
    /// machine.
    pub fn side(&self, o: Origin) -> Split {
        let u = match self.by {
            HoldOut::Robots => return split_of(self.seed, o.robot, self.fraction),
            HoldOut::Trajectories => unit(&[self.seed, o.robot, o.trajectory as u64, u64::MAX]),
            HoldOut::Windows => unit(&[self.seed, o.robot, o.trajectory as u64, o.segment as u64]),
        };
        if u < self.fraction { Split::Validation } else { Split::Train }
    }

    /// Whether `robot` is held out whole: only a split by robot holds any robot out whole, and the checks that need
    /// robots never seen in training (the torque and identification checks) run on those.
    pub fn holds_out_robot(&self, robot: u64) -> bool {
        self.by == HoldOut::Robots && split_of(self.seed, robot, self.fraction) == Split::Validation
    }
}

impl std::fmt::Display for SplitRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.0} % of the {} held out (seed {})", 100.0 * self.fraction, self.by.name(), self.seed)
    }
}

/// A number in [0, 1) from the hash of `key`.
fn unit(key: &[u64]) -> f64 {
    let bytes: Vec<u8> = key.iter().flat_map(|k| k.to_le_bytes()).collect();
    (content_hash(&bytes) >> 11) as f64 / (1u64 << 53) as f64
}

/// The time segment of each of a recording's `count` windows of geometry `spec`, listed as [`WindowSpec::windows`]
/// lists them: the k-th window of every offset ([`WindowSpec::places`]) is segment k, the same stretch of motion
/// shifted by multiples of the secondary sampling rate. Neighbouring segments overlap by at most `stride - ssr`
/// samples at their ends (48 of a window's 4,096 at 64:64:16), where a window of a late offset runs into the next
/// segment's first. Overlapping windows ([`WindowSpec::overlaps`]) chain every window of a recording to the next:
/// the recording is one segment.
pub fn segments(count: usize, spec: &WindowSpec) -> Vec<u32> {
    match spec.overlaps() {
        true => vec![0; count],
        false => spec.places(count).into_iter().map(|k| k as u32).collect(),
    }
}

/// Windows stored recording by recording with their robot and trajectory, each recording's together: per recording
/// its robot, trajectory and window count.
fn recordings(robots: &[u64], trajectories: &[u32]) -> Vec<(u64, u32, usize)> {
    let mut out = Vec::new();
    let mut first = 0;
    for i in 1..=robots.len() {
        if i == robots.len() || robots[i] != robots[first] || trajectories[i] != trajectories[first] {
            out.push((robots[first], trajectories[first], i - first));
            first = i;
        }
    }
    out
}

/// The origins of windows of geometry `spec` stored recording by recording with their robot and trajectory, each
/// recording's windows together as [`WindowSpec::windows`] lists them.
pub fn origins(robots: &[u64], trajectories: &[u32], spec: &WindowSpec) -> Vec<Origin> {
    recordings(robots, trajectories)
        .into_iter()
        .flat_map(|(robot, trajectory, count)| {
            segments(count, spec).into_iter().map(move |segment| Origin { robot, trajectory, segment })
        })
        .collect()
}

/// Of windows stored as [`origins`] reads them, which are back to back ([`WindowSpec::back_to_back`]).
pub fn back_to_back(robots: &[u64], trajectories: &[u32], spec: &WindowSpec) -> Vec<bool> {
    recordings(robots, trajectories).into_iter().flat_map(|(_, _, count)| spec.back_to_back(count)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_split_is_by_robot_deterministic_and_near_the_fraction() {
        let val = (0..10_000u64).filter(|&r| split_of(3, r, 0.2) == Split::Validation).count();
        // Binomial(10000, 0.2): sd = 40; 5 sd = 200.
        assert!((val as i64 - 2000).abs() < 200, "{val}");
        for r in 0..100 {
            assert_eq!(split_of(3, r, 0.2), split_of(3, r, 0.2));
        }
        let differs = (0..1000u64).filter(|&r| split_of(3, r, 0.5) != split_of(4, r, 0.5)).count();
        assert!(differs > 300, "another seed draws another split");
        assert_eq!(split_of(3, 7, 0.0), Split::Train);
        assert_eq!(split_of(3, 7, 1.0), Split::Validation);
    }

    /// 400 robots x 16 trajectories x 5 windows under each rule: the share held out is near the fraction, every
    /// window of a held-out unit is on one side, and the split by robot is `split_of` (old checkpoints keep theirs).
    #[test]
    fn each_rule_holds_out_its_unit_whole_and_near_the_fraction() {
        let grid: Vec<Origin> = (0..400u64)
            .flat_map(|robot| {
                (0..16u32)
                    .flat_map(move |trajectory| (0..5u32).map(move |segment| Origin { robot, trajectory, segment }))
            })
            .collect();
        for by in [HoldOut::Robots, HoldOut::Trajectories, HoldOut::Windows] {
            let rule = SplitRule { by, seed: 5, fraction: 0.2 };
            let held: Vec<&Origin> = grid.iter().filter(|o| rule.side(**o) == Split::Validation).collect();
            // Units: 400 robots (sd of the share 0.02), 6400 recordings (0.005), 32000 segments (0.0022); 5 sd.
            let share = held.len() as f64 / grid.len() as f64;
            let five_sd = match by {
                HoldOut::Robots => 0.1,
                HoldOut::Trajectories => 0.025,
                HoldOut::Windows => 0.011,
            };
            assert!((share - 0.2).abs() < five_sd, "{by:?}: {share}");
            let unit_of = |o: &Origin| match by {
                HoldOut::Robots => (o.robot, 0, 0),
                HoldOut::Trajectories => (o.robot, o.trajectory, 0),
                HoldOut::Windows => (o.robot, o.trajectory, o.segment),
            };
            let mut sides = std::collections::HashMap::new();
            for o in &grid {
                assert_eq!(*sides.entry(unit_of(o)).or_insert(rule.side(*o)), rule.side(*o), "{by:?} {o:?}");
            }
            let robots_with_both = (0..400u64)
                .filter(|&r| {
                    let s: std::collections::HashSet<Split> =
                        grid.iter().filter(|o| o.robot == r).map(|o| rule.side(*o)).collect();
                    s.len() == 2
                })
                .count();
            match by {
                HoldOut::Robots => {
                    assert_eq!(robots_with_both, 0);
                    assert!(grid.iter().all(|o| rule.side(*o) == split_of(5, o.robot, 0.2)));
                }
                // P(all 16 recordings on one side) = 0.8^16 + 0.2^16 = 2.8 %: almost every robot is on both sides.
                _ => assert!(robots_with_both > 350, "{by:?}: {robots_with_both}"),
            }
            assert_eq!(rule.holds_out_robot(3), by == HoldOut::Robots && split_of(5, 3, 0.2) == Split::Validation);
        }
    }

    /// Segments follow `WindowSpec::windows`' order for every recording length around the counts' steps, and
    /// origins restart them at each recording.
    #[test]
    fn segments_are_the_windows_places_in_time() {
        let spec = WindowSpec::default();
        for samples in (4000..30_000).step_by(97) {
            let windows = spec.windows(samples);
            let expected: Vec<u32> = windows.iter().map(|w| (w.start / spec.len) as u32).collect();
            assert_eq!(segments(windows.len(), &spec), expected, "{samples} samples");
            // Overlapping windows chain the whole recording into one segment.
            assert!(segments(spec.with_hop(32).windows(samples).len(), &spec.with_hop(32)).iter().all(|&s| s == 0));
        }
        // Two offsets (stride 2, SSR 1).
        let o = origins(&[1, 1, 1, 1, 1, 2], &[0, 0, 0, 1, 1, 1], &WindowSpec::new(4, 2, 1));
        let s: Vec<u32> = o.iter().map(|o| o.segment).collect();
        assert_eq!(s, [0, 1, 0, 0, 0, 0]);
        assert_eq!(o[4], Origin { robot: 1, trajectory: 1, segment: 0 });
    }

    /// Under the split by window, no validation window has a training window of its recording overlapping it by
    /// more than `stride - ssr` source samples (neighbouring segments' ends), over many seeds, and none at all where
    /// the windows overlap each other (hop 32); split window by window, as before, a window's offset siblings
    /// (shifted by 16 ms, 4,080 of 4,096 samples shared) land on both sides.
    #[test]
    fn the_split_by_window_keeps_a_windows_shifted_copies_on_its_side() {
        let back_to_back = WindowSpec::default();
        for (spec, allowed) in [(back_to_back, back_to_back.stride - back_to_back.ssr), (back_to_back.with_hop(32), 0)]
        {
            split_by_window_overlaps_at_most(spec, allowed);
        }
    }

    fn split_by_window_overlaps_at_most(spec: WindowSpec, allowed: usize) {
        let samples = 41_000;
        let windows = spec.windows(samples);
        let origins = origins(&vec![7; windows.len()], &vec![3; windows.len()], &spec);
        let overlap = |a: usize, b: usize| {
            let (x, y) = (spec.samples(&windows[a], samples), spec.samples(&windows[b], samples));
            y.end.min(x.end).saturating_sub(y.start.max(x.start))
        };
        let (mut largest, mut before) = (0, 0);
        for seed in 0..200 {
            let rule = SplitRule { by: HoldOut::Windows, seed, fraction: 0.3 };
            let side = |i: usize| rule.side(origins[i]);
            let by_window = |i: usize| unit(&[seed, 7, 3, i as u64]) < 0.3;
            for a in 0..windows.len() {
                for b in 0..windows.len() {
                    if side(a) == Split::Validation && side(b) == Split::Train {
                        largest = largest.max(overlap(a, b));
                    }
                    if by_window(a) && !by_window(b) {
                        before = before.max(overlap(a, b));
                    }
                }
            }
        }
        assert!(largest <= allowed, "{spec}: {largest}");
        assert_eq!(before, spec.len * spec.stride - spec.ssr, "{spec}");
    }
}
