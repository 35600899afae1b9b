//! Finite Fourier series per joint (Swevers et al., 1997), the classical excitation: periodic, so a trajectory can
//! be repeated and averaged, band-limited by its harmonic count, and with its derivatives in closed form. Written to
//! start and end at rest at a given pose. A contract: `dynforge excite` writes it (`excitation-K.json`), the family's
//! workers follow it.

use serde::{Deserialize, Serialize};

/// `q_j(t) = q0_j + sum_l [a_jl sin(w l t) + b_jl (1 - cos(w l t))] / (w l)` with `w = 2 pi / period`, so
/// `q(0) = q(period) = q0`, `qd = sum_l a_jl cos(w l t) + b_jl sin(w l t)` and
/// `qdd = sum_l w l (b_jl cos(w l t) - a_jl sin(w l t))`. At rest at both ends: `sum_l a_jl = 0` and
/// `sum_l l b_jl = 0`, held by the last harmonic's coefficients ([`Fourier::from_free`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fourier {
    /// One period [s]: the trajectory's duration.
    pub period: f64,
    /// The pose at the start and the end [rad or m].
    pub start: Vec<f64>,
    /// Per joint, the coefficients of harmonics 1..=L [rad/s or m/s].
    pub a: Vec<Vec<f64>>,
    pub b: Vec<Vec<f64>>,
}

/// An excitation as `dynforge excite` writes it (`excitation-K.json`): the series and the joints it moves, in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Excitation {
    pub joints: Vec<String>,
    pub series: Fourier,
}

impl Fourier {
    /// Free coefficients per joint: `2 (L - 1)` (the last harmonic's two are fixed by rest at both ends).
    pub fn free_per_joint(harmonics: usize) -> usize {
        2 * (harmonics - 1)
    }

    /// The series with the free coefficients `x` (per joint `a_1..a_(L-1)`, then `b_1..b_(L-1)`).
    pub fn from_free(period: f64, start: &[f64], harmonics: usize, x: &[f64]) -> Self {
        let (n, k) = (start.len(), Self::free_per_joint(harmonics));
        let last = harmonics as f64;
        let (mut a, mut b) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for j in 0..n {
            let free = &x[j * k..(j + 1) * k];
            let mut aj = free[..harmonics - 1].to_vec();
            let mut bj = free[harmonics - 1..].to_vec();
            aj.push(-aj.iter().sum::<f64>());
            bj.push(-bj.iter().enumerate().map(|(l, v)| (l + 1) as f64 * v).sum::<f64>() / last);
            a.push(aj);
            b.push(bj);
        }
        Fourier { period, start: start.to_vec(), a, b }
    }

    pub fn joints(&self) -> usize {
        self.start.len()
    }

    /// Position, velocity and acceleration of every joint at `t`, into the slices.
    pub fn at(&self, t: f64, q: &mut [f64], qd: &mut [f64], qdd: &mut [f64]) {
        let w = std::f64::consts::TAU / self.period;
        for j in 0..self.joints() {
            let (mut x, mut v, mut acc) = (self.start[j], 0.0, 0.0);
            for (l, (a, b)) in self.a[j].iter().zip(&self.b[j]).enumerate() {
                let wl = w * (l + 1) as f64;
                let (s, c) = (wl * t).sin_cos();
                x += (a * s + b * (1.0 - c)) / wl;
                v += a * c + b * s;
                acc += wl * (b * c - a * s);
            }
            (q[j], qd[j], qdd[j]) = (x, v, acc);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Derivatives against central differences of the closed form, and rest at both ends whatever the free
    /// coefficients.
    #[test]
    fn the_series_starts_and_ends_at_rest_and_its_derivatives_are_exact() {
        let x: Vec<f64> = (0..2 * Fourier::free_per_joint(4)).map(|k| ((k * 7919) % 13) as f64 / 13.0 - 0.4).collect();
        let f = Fourier::from_free(8.0, &[0.3, -1.0], 4, &x);
        let eval = |t: f64| {
            let (mut q, mut qd, mut qdd) = ([0.0; 2], [0.0; 2], [0.0; 2]);
            f.at(t, &mut q, &mut qd, &mut qdd);
            (q, qd, qdd)
        };
        for t in [0.0, 8.0] {
            let (q, qd, qdd) = eval(t);
            for j in 0..2 {
                assert!((q[j] - f.start[j]).abs() < 1e-12 && qd[j].abs() < 1e-12 && qdd[j].abs() < 1e-12, "{t}");
            }
        }
        // Central differences: error h^2 / 6 times the third derivative, here < 1e-5 with h = 1e-4.
        let h = 1e-4;
        for t in [0.7, 3.3, 6.1] {
            let ((qm, qdm, _), (q, qd, qdd), (qp, qdp, _)) = (eval(t - h), eval(t), eval(t + h));
            for j in 0..2 {
                assert!(((qp[j] - qm[j]) / (2.0 * h) - qd[j]).abs() < 1e-5, "{t} {j}");
                assert!(((qdp[j] - qdm[j]) / (2.0 * h) - qdd[j]).abs() < 1e-5, "{t} {j}");
                let _ = q;
            }
        }
    }
}
