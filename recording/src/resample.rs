//! Timestep unification: every channel linearly interpolated onto a fixed grid `t0, t0 + dt, ...` spanning the
//! recording. Real logs are irregular and drop samples; ours are already at 1 kHz, where this is the identity.

use crate::samples::JointTrajectory;

/// Resamples onto the grid of period `dt` starting at the first sample, up to the last sample.
pub fn resample(traj: &JointTrajectory, dt: f64) -> JointTrajectory {
    assert!(dt > 0.0, "the resampling period must be positive");
    let n = traj.joints();
    let mut out = JointTrajectory { names: traj.names.clone(), ..JointTrajectory::default() };
    let (Some(&t0), Some(&t_end)) = (traj.t.first(), traj.t.last()) else { return out };
    // A tolerance of 1e-9 dt keeps the last grid point when t_end is a grid point up to rounding.
    let samples = ((t_end - t0) / dt + 1e-9).floor() as usize + 1;
    let mut seg = 0;
    for k in 0..samples {
        let t = t0 + k as f64 * dt;
        while seg + 2 < traj.len() && traj.t[seg + 1] < t {
            seg += 1;
        }
        let (i, j) = if traj.len() == 1 { (0, 0) } else { (seg, seg + 1) };
        let span = traj.t[j] - traj.t[i];
        let w = if span > 0.0 { ((t - traj.t[i]) / span).clamp(0.0, 1.0) } else { 0.0 };
        out.t.push(t);
        for (dst, src) in [(&mut out.q, &traj.q), (&mut out.qd, &traj.qd), (&mut out.tau, &traj.tau)] {
            for c in 0..n {
                let (a, b) = (src[i * n + c], src[j * n + c]);
                dst.push(a + w * (b - a));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(times: &[f64]) -> JointTrajectory {
        let mut t = JointTrajectory { names: vec!["a".into(), "b".into()], ..Default::default() };
        for &s in times {
            t.t.push(s);
            t.q.extend([2.0 * s + 1.0, -s]);
            t.qd.extend([2.0, -1.0]);
            t.tau.extend([0.5 * s, 3.0]);
        }
        t
    }

    #[test]
    fn a_resampled_ramp_stays_a_ramp() {
        // Irregular stamps with a dropped stretch: linear data is reproduced exactly (to rounding) on the grid.
        let times = [0.0, 0.0013, 0.0021, 0.0030, 0.0105, 0.0111, 0.0127, 0.0200];
        let r = resample(&ramp(&times), 1e-3);
        assert_eq!(r.len(), 21);
        for (k, &t) in r.t.iter().enumerate() {
            assert!((t - k as f64 * 1e-3).abs() < 1e-15);
            assert!((r.q[2 * k] - (2.0 * t + 1.0)).abs() < 1e-12 && (r.q[2 * k + 1] + t).abs() < 1e-12);
            assert!((r.tau[2 * k] - 0.5 * t).abs() < 1e-12 && r.tau[2 * k + 1] == 3.0);
            assert_eq!((r.qd[2 * k], r.qd[2 * k + 1]), (2.0, -1.0));
        }
    }

    #[test]
    fn a_regular_recording_is_unchanged() {
        let times: Vec<f64> = (0..50).map(|k| k as f64 * 1e-3).collect();
        let src = ramp(&times);
        let r = resample(&src, 1e-3);
        assert_eq!(r.len(), src.len());
        for (a, b) in r.q.iter().zip(&src.q) {
            assert!((a - b).abs() < 1e-12);
        }
    }
}
