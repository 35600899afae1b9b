//! Train/validation splits, deterministic from a seed. By robot (the default): no validation robot is ever seen in
//! training, which is what a user's new robot is. By trajectory or by window: validation data come from robots seen
//! in training with other recordings or other windows, the protocols a paper may have used without saying so
//! (a network that recognises a robot by its kinematics can recall its parameters there).

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
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum HoldOut {
    /// Whole robots.
    #[default]
    Robots,
    /// Whole recordings, of robots whose other recordings are trained on.
    Trajectories,
    /// Windows drawn across all robots and recordings.
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

/// Where a window comes from: its robot, the recording (the robot's trajectory index) and its place in the
/// recording (0, 1, ... in time order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Origin {
    pub robot: u64,
    pub trajectory: u32,
    pub window: u32,
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
    /// trajectory; or all three), so every window of a held-out unit is on the same side, on every machine.
    pub fn side(&self, o: Origin) -> Split {
        let u = match self.by {
            HoldOut::Robots => return split_of(self.seed, o.robot, self.fraction),
            HoldOut::Trajectories => unit(&[self.seed, o.robot, o.trajectory as u64, u64::MAX]),
            HoldOut::Windows => unit(&[self.seed, o.robot, o.trajectory as u64, o.window as u64]),
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

/// The origins of windows stored in recording order with their robot and trajectory: each window's place in its
/// recording is its count among the windows of the same recording before it (a recording's windows are stored
/// together, in time order).
pub fn origins(robots: &[u64], trajectories: &[u32]) -> Vec<Origin> {
    let mut out = Vec::with_capacity(robots.len());
    let mut window = 0;
    for (i, (&robot, &trajectory)) in robots.iter().zip(trajectories).enumerate() {
        let same = i > 0 && robots[i - 1] == robot && trajectories[i - 1] == trajectory;
        window = if same { window + 1 } else { 0 };
        out.push(Origin { robot, trajectory, window });
    }
    out
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
                (0..16u32).flat_map(move |trajectory| (0..5u32).map(move |window| Origin { robot, trajectory, window }))
            })
            .collect();
        for by in [HoldOut::Robots, HoldOut::Trajectories, HoldOut::Windows] {
            let rule = SplitRule { by, seed: 5, fraction: 0.2 };
            let held: Vec<&Origin> = grid.iter().filter(|o| rule.side(**o) == Split::Validation).collect();
            // Units: 400 robots (sd of the share 0.02), 6400 recordings (0.005), 32000 windows (0.0022); 5 sd.
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
                HoldOut::Windows => (o.robot, o.trajectory, o.window),
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

    #[test]
    fn origins_count_windows_within_each_recording() {
        let o = origins(&[1, 1, 1, 1, 2], &[0, 0, 1, 1, 1]);
        let w: Vec<u32> = o.iter().map(|o| o.window).collect();
        assert_eq!(w, [0, 1, 0, 1, 0]);
        assert_eq!(o[3], Origin { robot: 1, trajectory: 1, window: 1 });
    }
}
