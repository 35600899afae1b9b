//! A link's inertial parameters in the coordinates identification searches and a family is drawn in: the log-Cholesky factor of its
//! pseudo-inertia (Rucker & Wensing, "Smooth Parameterization of Rigid-Body Inertia", RA-L 2022).
//!
//! The 4x4 pseudo-inertia `J = [[Sigma, h], [h^T, m]]` (`Sigma = tr(I_o)/2 1 - I_o`, the second moments about the
//! link frame's origin; `h = m c`) is positive definite exactly when the link is a physical body: positive mass and
//! principal moments obeying the triangle inequalities strictly (Wensing, Kim, Slotine, RA-L 2017). Writing
//! `J = U U^T` with
//!
//! ```text
//! U = e^a [[e^d1, s12, s13, t1],
//!          [0,    e^d2, s23, t2],
//!          [0,    0,    e^d3, t3],
//!          [0,    0,    0,    1 ]]
//! ```
//!
//! every real vector `theta = (a, d1, d2, d3, s12, s23, s13, t1, t2, t3)` is a physical body, and every physical
//! body has one: a search over `theta` never leaves physics and needs no projection afterwards. The coordinates
//! read directly: `m = e^(2a)`, the centre of mass is `t`, and `m V V^T` (`V` the upper 3x3 of `U / e^a`) is the
//! second-moment matrix about the COM, so `d` are log radii of gyration.

use crate::spatial::Inertia;
use nalgebra::{Matrix3, Matrix4, Vector3};

/// Coordinates per link.
pub const COORDINATES: usize = 10;

/// Index of each coordinate in a link's block.
pub const ALPHA: usize = 0;
pub const D: [usize; 3] = [1, 2, 3];
pub const S: [usize; 3] = [4, 5, 6];
pub const T: [usize; 3] = [7, 8, 9];

/// The dynamic parameters `[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]` (inertia about the link origin;
/// `dynforge_proto::params`) of the pseudo-inertia `j`.
fn params_of(j: &Matrix4<f64>) -> [f64; COORDINATES] {
    Inertia::from_pseudo(j).to_params()
}

/// `U` of coordinates `theta`.
fn factor(theta: &[f64]) -> Matrix4<f64> {
    let e = theta[ALPHA].exp();
    let mut u = Matrix4::zeros();
    for k in 0..3 {
        u[(k, k)] = e * theta[D[k]].exp();
        u[(k, 3)] = e * theta[T[k]];
    }
    u[(0, 1)] = e * theta[S[0]];
    u[(1, 2)] = e * theta[S[1]];
    u[(0, 2)] = e * theta[S[2]];
    u[(3, 3)] = e;
    u
}

/// The dynamic parameters of a link at coordinates `theta`.
pub fn params(theta: &[f64]) -> [f64; COORDINATES] {
    let u = factor(theta);
    params_of(&(u * u.transpose()))
}

/// `d params / d theta`, column `k` the derivative along coordinate `k`: with `J = U U^T`,
/// `dJ = dU U^T + U dU^T`, and the map from `J` to the parameters is linear.
pub fn jacobian(theta: &[f64]) -> [[f64; COORDINATES]; COORDINATES] {
    let u = factor(theta);
    let e = theta[ALPHA].exp();
    let mut out = [[0.0; COORDINATES]; COORDINATES];
    for (k, column) in out.iter_mut().enumerate() {
        let mut du = Matrix4::zeros();
        match k {
            ALPHA => du = u,
            1..=3 => du[(k - 1, k - 1)] = u[(k - 1, k - 1)],
            4 => du[(0, 1)] = e,
            5 => du[(1, 2)] = e,
            6 => du[(0, 2)] = e,
            _ => du[(k - T[0], 3)] = e,
        }
        let dj = du * u.transpose() + u * du.transpose();
        *column = params_of(&dj);
    }
    out
}

/// The coordinates of dynamic parameters `p`, or `None` when they are no physical body (the pseudo-inertia is not
/// positive definite). `U` is the "upper" Cholesky factor, that of the exchange-permuted pseudo-inertia.
pub fn coordinates(p: &[f64]) -> Option<[f64; COORDINATES]> {
    let j = Inertia::from_params(p.try_into().ok()?).pseudo();
    let swap = |m: &Matrix4<f64>| Matrix4::from_fn(|r, c| m[(3 - r, 3 - c)]);
    let l = nalgebra::Cholesky::new(swap(&j))?.l();
    let u = swap(&l);
    let e = u[(3, 3)];
    let mut theta = [0.0; COORDINATES];
    theta[ALPHA] = e.ln();
    for k in 0..3 {
        theta[D[k]] = (u[(k, k)] / e).ln();
        theta[T[k]] = u[(k, 3)] / e;
    }
    theta[S[0]] = u[(0, 1)] / e;
    theta[S[1]] = u[(1, 2)] / e;
    theta[S[2]] = u[(0, 2)] / e;
    theta.iter().all(|v| v.is_finite()).then_some(theta)
}

/// A link's parameters as a URDF states them: mass, centre of mass in the link frame, and the inertia about the COM
/// `[ixx, ixy, ixz, iyy, iyz, izz]` in the axes of `rotation` (the URDF's `<inertial><origin rpy>`), given as the
/// rotation of those axes in the link frame.
pub fn standard(p: &[f64], rotation: &Matrix3<f64>) -> (f64, [f64; 3], [f64; 6]) {
    let m = p[0];
    let c = Vector3::new(p[1], p[2], p[3]) / m;
    let io = Matrix3::new(p[4], p[5], p[7], p[5], p[6], p[8], p[7], p[8], p[9]);
    // Parallel axis: I_c = I_o - m (|c|^2 1 - c c^T).
    let ic = io - m * (Matrix3::identity() * c.dot(&c) - c * c.transpose());
    let r = rotation.transpose() * ic * rotation;
    (m, [c.x, c.y, c.z], [r[(0, 0)], r[(0, 1)], r[(0, 2)], r[(1, 1)], r[(1, 2)], r[(2, 2)]])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A physical link: 2.5 kg, COM off-axis, a full inertia tensor about the COM.
    fn link() -> [f64; 10] {
        let (m, c) = (2.5, Vector3::new(0.02, -0.01, 0.15));
        let ic = Matrix3::new(0.03, 0.002, -0.001, 0.002, 0.025, 0.003, -0.001, 0.003, 0.01);
        let io = ic + m * (Matrix3::identity() * c.dot(&c) - c * c.transpose());
        [m, m * c.x, m * c.y, m * c.z, io[(0, 0)], io[(0, 1)], io[(1, 1)], io[(0, 2)], io[(1, 2)], io[(2, 2)]]
    }

    #[test]
    fn coordinates_and_parameters_round_trip() {
        let p = link();
        let theta = coordinates(&p).expect("a physical link has coordinates");
        assert!((theta[ALPHA] - 0.5 * 2.5f64.ln()).abs() < 1e-14, "a = ln(m) / 2");
        assert!((theta[T[2]] - 0.15).abs() < 1e-14, "t is the centre of mass");
        let back = params(&theta);
        for (a, b) in back.iter().zip(&p) {
            assert!((a - b).abs() < 1e-14 * p[0], "{back:?} vs {p:?}");
        }
    }

    #[test]
    fn every_coordinate_vector_is_a_physical_body() {
        let mut rng = crate::rng::Rng::stream(5, &[]);
        for _ in 0..1000 {
            let theta: Vec<f64> = (0..COORDINATES).map(|_| rng.uniform(-3.0, 3.0)).collect();
            let p = params(&theta);
            let inertia = crate::spatial::Inertia::from_params(&p);
            crate::model::check_physical(&inertia).unwrap_or_else(|e| panic!("{theta:?}: {e}"));
        }
        // And a body that is not physical (a principal moment above the sum of the others) has none.
        let mut p = link();
        p[9] += 1.0;
        assert!(coordinates(&p).is_none());
    }

    #[test]
    fn the_jacobian_is_the_derivative() {
        let theta = coordinates(&link()).unwrap();
        let jac = jacobian(&theta);
        // Central differences of a smooth map: error h^2 |third derivative| ~ 1e-10 at h = 1e-5.
        let h = 1e-5;
        for k in 0..COORDINATES {
            let (mut up, mut down) = (theta, theta);
            up[k] += h;
            down[k] -= h;
            let (pu, pd) = (params(&up), params(&down));
            for r in 0..COORDINATES {
                let fd = (pu[r] - pd[r]) / (2.0 * h);
                assert!((fd - jac[k][r]).abs() < 1e-8 * (1.0 + fd.abs()), "d p{r} / d theta{k}: {fd} vs {}", jac[k][r]);
            }
        }
    }

    #[test]
    fn standard_parameters_are_the_urdf_s() {
        let (m, c, i) = standard(&link(), &Matrix3::identity());
        assert!((m - 2.5).abs() < 1e-15 && (c[2] - 0.15).abs() < 1e-15);
        let want = [0.03, 0.002, -0.001, 0.025, 0.003, 0.01];
        assert!(i.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-15), "{i:?}");
    }
}
