//! What an excitation design is asked for: its size and the limits it stays within.

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
    /// Torque noise per joint, or one for all [N m or N]: each joint's torques weigh by its inverse in the design's
    /// information, and the report's expected deviations assume it.
    pub noise: Vec<f64>,
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
            noise: vec![0.1],
            rate: 50.0,
            evaluations: 1500,
            seed: 0,
        }
    }
}

/// Rate [Hz] the final trajectories' efforts are checked at.
pub(crate) const DENSE_RATE: f64 = 1000.0;
