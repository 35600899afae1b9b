//! The labels that best explain the recorded torques given a prior belief about them.

use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_robot::Model;
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::labels::parameters_of_labels;
use crate::normal::NormalEquations;
use crate::solve::pseudo_solve;

/// Smallest torque noise level assumed, as a fraction of the recorded torques' RMS. Simulated data are noise-free
/// up to the integration scheme (the true parameters leave ~2e-4 of the torque spread), and a real robot's model is
/// never better than its torque sensing; without a floor an exact fit would give the prior no say at all and the
/// solve would be as ill-conditioned as the data.
pub const NOISE_FLOOR: f64 = 1e-3;

/// Independent Gaussian beliefs about the 38 labels [SI], each label its own unknown. A full covariance (the
/// training robots' label correlations, the network's error correlations) would let the refinement trade labels
/// along correlated directions into unphysical values that the URDF's projection then undoes; tying the
/// generator's equal labels (`Ixx == Iyy` of every link) into one unknown scores worse on inertia. Both measured in
/// `docs/training.md`.
#[derive(Debug, Clone)]
pub struct Prior {
    pub mean: [f64; NUM_LABELS],
    std: [f64; NUM_LABELS],
}

impl Prior {
    /// Labels `mean` with standard deviations `std`, each positive.
    pub fn new(mean: [f64; NUM_LABELS], std: &[f64; NUM_LABELS]) -> Result<Self, IdentifyError> {
        for (l, &s) in LABELS.iter().zip(std) {
            if !(s > 0.0 && s.is_finite()) {
                return Err(IdentifyError::Prior(l.name, s));
            }
        }
        Ok(Prior { mean, std: *std })
    }

    pub fn std(&self) -> &[f64; NUM_LABELS] {
        &self.std
    }
}

/// The refined labels.
#[derive(Debug, Clone)]
pub struct Refined {
    pub labels: [f64; NUM_LABELS],
    /// Posterior standard deviation of each label [SI] (Laplace: the Gauss-Newton Hessian at the optimum), the
    /// prior's where the torques say nothing of it.
    pub std: [f64; NUM_LABELS],
    /// Gauss-Newton iterations taken.
    pub iterations: usize,
    /// Whether the torque noise assumed was [`NOISE_FLOOR`] rather than the residual's (a simulated log's: the
    /// posterior is then as wide as the floor, not as the data).
    pub at_floor: bool,
}

/// Maximum a posteriori labels: minimises `|Y pi(y) - tau|^2 / sigma^2 + sum_k ((y_k - mean_k) / std_k)^2` by
/// Gauss-Newton with step halving (`pi(y)` is polynomial in the labels, nearly linear over the prior's range).
/// `template` supplies the kinematics and what the labels do not cover; `sigma` is the torque noise level (e.g.
/// [`crate::LeastSquares::sigma`]), raised to [`NOISE_FLOOR`] of the torques' RMS.
pub fn refine(ne: &NormalEquations, template: &Model, prior: &Prior, sigma: f64) -> Result<Refined, IdentifyError> {
    if ne.rows() == 0 {
        return Err(IdentifyError::NoData);
    }
    let (a, b, c) = ne.gram();
    let floor = NOISE_FLOOR * (c / ne.rows() as f64).sqrt();
    let at_floor = sigma <= floor;
    let sigma = sigma.max(floor);
    let w = 1.0 / (sigma * sigma);
    // Work in prior-standardised coordinates z = (y - mean) / std: the prior term is |z|^2 and H >= I.
    let labels =
        |z: &DVector<f64>| -> [f64; NUM_LABELS] { std::array::from_fn(|k| prior.mean[k] + prior.std[k] * z[k]) };
    let params = |z: &DVector<f64>| DVector::from_vec(parameters_of_labels(template, &labels(z)));
    let objective = |pi: &DVector<f64>, z: &DVector<f64>| {
        w * (pi.dot(&(&a * pi)) - 2.0 * b.dot(pi) + c).max(0.0) + z.norm_squared()
    };
    // Jacobian of pi by central differences (exact to rounding for the quadratic terms, O(h^2) for m c^2).
    let jacobian = |z: &DVector<f64>| {
        let h = 1e-3;
        let mut g = DMatrix::zeros(parameters_of_labels(template, &labels(z)).len(), NUM_LABELS);
        for k in 0..NUM_LABELS {
            let (mut up, mut down) = (z.clone(), z.clone());
            up[k] += h;
            down[k] -= h;
            g.set_column(k, &((params(&up) - params(&down)) / (2.0 * h)));
        }
        g
    };
    let mut z = DVector::zeros(NUM_LABELS);
    let mut pi = params(&z);
    let mut f = objective(&pi, &z);
    let mut iterations = 0;
    for _ in 0..100 {
        iterations += 1;
        let g = jacobian(&z);
        let grad = g.transpose() * (&a * &pi - &b) * w + &z;
        let hess = g.transpose() * &a * &g * w + DMatrix::identity(NUM_LABELS, NUM_LABELS);
        let (step, _) = pseudo_solve(&hess, &(-grad), 0.0)?;
        let mut alpha = 1.0;
        let mut improved = false;
        for _ in 0..30 {
            let z_new = &z + &step * alpha;
            let pi_new = params(&z_new);
            let f_new = objective(&pi_new, &z_new);
            if f_new <= f {
                improved = f - f_new > 1e-14 * f.max(1.0);
                (z, pi, f) = (z_new, pi_new, f_new);
                break;
            }
            alpha *= 0.5;
        }
        if !improved || step.amax() * alpha < 1e-10 {
            break;
        }
    }
    // The posterior covariance of z is the inverse Hessian (its eigenvalues are at least 1: the prior).
    let g = jacobian(&z);
    let hess = g.transpose() * &a * &g * w + DMatrix::identity(NUM_LABELS, NUM_LABELS);
    let (vectors, values) = crate::solve::eigen(&hess)?;
    let std = std::array::from_fn(|k| {
        let var: f64 = (0..NUM_LABELS).map(|e| vectors[(k, e)].powi(2) / values[e].max(1.0)).sum();
        prior.std[k] * var.sqrt()
    });
    Ok(Refined { labels: labels(&z), std, iterations, at_floor })
}
