//! Joint motions that start and end at rest: the design's Fourier series, and the random multi-sines it is measured
//! against (the usual way to excite a robot without a design).

use dynforge_proto::fourier::Fourier;
use dynforge_robot::rng::Rng;

/// A joint trajectory over `[0, duration]`: positions, velocities and accelerations at any time.
pub trait Motion: Sync {
    fn duration(&self) -> f64;
    /// Position, velocity and acceleration of every joint at `t`, into the slices.
    fn at(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]);
}

impl Motion for Fourier {
    fn duration(&self) -> f64 {
        self.period
    }

    fn at(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        Fourier::at(self, t, q, qd, qdd)
    }
}

/// Sines per joint of a random multi-sine, and the band their frequencies are drawn from [Hz].
pub const SINES: usize = 5;
pub const BAND: (f64, f64) = (0.1, 1.0);

/// A random multi-sine: per joint `q_j = q0_j + c_j w(t) sum_k sin(omega_jk t + phi_jk) / omega_jk`, with `w` a
/// quintic fade-in and fade-out (zero with its first two derivatives at both ends, so the motion starts and ends at
/// rest at `q0`) and `c_j` the joint's scale.
#[derive(Debug, Clone, PartialEq)]
pub struct MultiSine {
    pub duration: f64,
    /// Length of the fade at either end [s].
    pub fade: f64,
    pub start: Vec<f64>,
    /// Per joint the angular frequencies [rad/s] and phases [rad].
    pub omega: Vec<Vec<f64>>,
    pub phase: Vec<Vec<f64>>,
    pub scale: Vec<f64>,
}

impl MultiSine {
    /// [`SINES`] frequencies per joint uniform in [`BAND`], uniform phases, unit scales.
    pub fn draw(duration: f64, fade: f64, start: &[f64], rng: &mut Rng) -> Self {
        let n = start.len();
        let omega =
            (0..n).map(|_| (0..SINES).map(|_| std::f64::consts::TAU * rng.uniform(BAND.0, BAND.1)).collect()).collect();
        let phase = (0..n).map(|_| (0..SINES).map(|_| rng.uniform(0.0, std::f64::consts::TAU)).collect()).collect();
        MultiSine { duration, fade, start: start.to_vec(), omega, phase, scale: vec![1.0; n] }
    }

    /// The fade window and its first two derivatives at `t`.
    fn window(&self, t: f64) -> (f64, f64, f64) {
        let (up, dup, ddup) = smoothstep(t / self.fade);
        let (down, ddown, dddown) = smoothstep((self.duration - t) / self.fade);
        let (dup, ddup) = (dup / self.fade, ddup / self.fade.powi(2));
        let (ddown, dddown) = (-ddown / self.fade, dddown / self.fade.powi(2));
        (up * down, dup * down + up * ddown, ddup * down + 2.0 * dup * ddown + up * dddown)
    }
}

/// `10 x^3 - 15 x^4 + 6 x^5` on [0, 1] (0 below, 1 above) with its first two derivatives in `x`.
fn smoothstep(x: f64) -> (f64, f64, f64) {
    if x <= 0.0 {
        return (0.0, 0.0, 0.0);
    }
    if x >= 1.0 {
        return (1.0, 0.0, 0.0);
    }
    let x2 = x * x;
    (x2 * x * (10.0 - 15.0 * x + 6.0 * x2), 30.0 * x2 * (1.0 - x).powi(2), 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x))
}

impl Motion for MultiSine {
    fn duration(&self) -> f64 {
        self.duration
    }

    fn at(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let (w, dw, ddw) = self.window(t);
        for j in 0..self.start.len() {
            let (mut s, mut ds, mut dds) = (0.0, 0.0, 0.0);
            for (omega, phase) in self.omega[j].iter().zip(&self.phase[j]) {
                let (sin, cos) = (omega * t + phase).sin_cos();
                s += sin / omega;
                ds += cos;
                dds -= omega * sin;
            }
            let c = self.scale[j];
            q[j] = self.start[j] + c * w * s;
            qd[j] = c * (dw * s + w * ds);
            qdd[j] = c * (ddw * s + 2.0 * dw * ds + w * dds);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At rest at the start pose at both ends, and the derivatives are those of the positions. Central differences
    /// err by h^2/6 times the next derivative: with h = 1e-4, scales up to 1.3, five frequencies under 2 pi rad/s
    /// and a 1 s fade (window derivatives up to 1.9, 5.8, 60), the fourth derivative stays under 4,400, so under
    /// 7.5e-6.
    #[test]
    fn a_multisine_starts_and_ends_at_rest_and_its_derivatives_are_exact() {
        let mut rng = Rng::stream(3, &[0]);
        let m = MultiSine { scale: vec![0.7, 1.3], ..MultiSine::draw(6.0, 1.0, &[0.2, -0.5], &mut rng) };
        let eval = |t: f64| {
            let (mut q, mut qd, mut qdd) = ([0.0; 2], [0.0; 2], [0.0; 2]);
            m.at(t, &mut q, &mut qd, &mut qdd);
            (q, qd, qdd)
        };
        for t in [0.0, 6.0] {
            let (q, qd, qdd) = eval(t);
            assert_eq!((q, qd, qdd), ([0.2, -0.5], [0.0; 2], [0.0; 2]), "{t}");
        }
        let h = 1e-4;
        // Inside the fades (0.5, 5.7) and between them (3.1).
        for t in [0.5, 3.1, 5.7] {
            let ((qm, qdm, _), (_, qd, qdd), (qp, qdp, _)) = (eval(t - h), eval(t), eval(t + h));
            for j in 0..2 {
                assert!(((qp[j] - qm[j]) / (2.0 * h) - qd[j]).abs() < 1e-5, "{t} {j}");
                assert!(((qdp[j] - qdm[j]) / (2.0 * h) - qdd[j]).abs() < 1e-5, "{t} {j}");
            }
        }
        for row in &m.omega {
            assert!(row.iter().all(|w| (BAND.0..=BAND.1).contains(&(w / std::f64::consts::TAU))));
        }
    }
}
