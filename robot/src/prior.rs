//! A Gaussian prior over a robot's parameters in coordinates where every point is a physical robot: per link the
//! log-Cholesky coordinates of its inertia (`crate::spatial::log_cholesky`), then per joint its Coulomb and viscous
//! friction, then per joint its drive's armature and offset (`crate::drive`). It lives beside the inertia it
//! parameterizes because two sides use it: identification searches these coordinates under this prior, and a robot's
//! family is drawn from it (every draw a physical body).

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_proto::spread::Spread;
use nalgebra::{DMatrix, DVector};

use crate::Model;
use crate::drive::{self, DRIVE_PER_JOINT as ND, identified_len};
use crate::parameters::dynamic_parameters;
use crate::spatial::log_cholesky::{self as standard, ALPHA, COORDINATES, D, S, T};

/// Why a prior could not be built or drawn from.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PriorError {
    #[error("{0}: not a physical body (its pseudo-inertia is not positive definite)")]
    NotPhysical(String),
}

/// A Gaussian prior over the coordinates `x` (per link its log-Cholesky coordinates, then per joint Coulomb and
/// viscous friction, then per joint its drive's armature and offset: `crate::drive`). Independent in each link's mass, the scale of its inertia tensor and the tensor's shape (the
/// coordinates `independent` maps a link's log mass and log radii to) and in every other coordinate: a URDF's mass,
/// inertia and centre of mass come from different sources (a scale, a CAD model's geometry, a guess) and are off
/// independently, while the geometry that gives the tensor's shape is what a URDF gets best.
#[derive(Debug, Clone, PartialEq)]
pub struct CoordinatePrior {
    pub mean: DVector<f64>,
    /// Standard deviations of the independent coordinates (`independent(x - mean)`).
    std: DVector<f64>,
    links: usize,
}

/// The friction a joint is taken to have when its URDF states less (most state none, which is no evidence that there
/// is none): Coulomb as a share of the joint's effort limit, viscous of its effort limit over its speed limit. The
/// prior believes friction within its kind's spread of the larger of this and the URDF's value, so `--spread
/// friction=` widens an unknown friction as it widens a stated one. Geared arms have Coulomb friction of 0.5-5 % of
/// their effort limit and viscous 1-10 % (a UR10e's wrists: about 3 N m s/rad against 56 N m at 3.1 rad/s); at the
/// default spread of 0.5 these put such friction within two standard deviations of none.
pub const TYPICAL_FRICTION: (f64, f64) = (0.1, 0.2);

/// How much better than its scale a link's inertia tensor's shape is known: the spread of each principal radius
/// about the radii's geometric mean, as a share of the spread of the scale.
pub const SHAPE: f64 = 0.5;

/// Independent coordinates of a link's `[a, d1, d2, d3]`: the log mass (over two), the log scale of the inertia
/// tensor (over two: `a` plus the mean log radius), and the first two radii's log deviations from their mean. The
/// coordinates of `x` other than these are their own independent ones.
fn independent(v: [f64; 4]) -> [f64; 4] {
    let mean = (v[1] + v[2] + v[3]) / 3.0;
    [v[0], v[0] + mean, v[1] - mean, v[2] - mean]
}

/// The inverse of [`independent`].
fn from_independent(y: [f64; 4]) -> [f64; 4] {
    let mean = y[1] - y[0];
    [y[0], mean + y[2], mean + y[3], mean - y[2] - y[3]]
}

/// Indices in `x` of link `l`'s `[a, d1, d2, d3]`.
fn mass_and_radii(l: usize) -> [usize; 4] {
    [COORDINATES * l + ALPHA, COORDINATES * l + D[0], COORDINATES * l + D[1], COORDINATES * l + D[2]]
}

impl CoordinatePrior {
    /// The prior of a robot description: its own values, each believed to within its kind's `spread` (relative):
    /// the mass and the inertia tensor's scale log-normally (`a` and the log scale with half the mass's and the
    /// inertia's spread), the tensor's shape within [`SHAPE`] of its scale, the off-diagonal shape within half the
    /// inertia's spread of the link's radius of gyration, the centre of mass within the COM's spread of its distance
    /// from the link's origin (at least 1 cm) in every direction, friction within its spread of its value or
    /// [`TYPICAL_FRICTION`], the drives' terms about none, within spreads sized from the joint's effort limit
    /// (`crate::drive::prior`).
    pub fn of(model: &Model, spread: Spread) -> Result<Self, PriorError> {
        let n = model.dof();
        let pi = dynamic_parameters(model);
        let mut mean = DVector::zeros(coordinates(n));
        let mut std = DVector::zeros(coordinates(n));
        for l in 0..n {
            let theta = standard::coordinates(&pi[NI * l..NI * (l + 1)])
                .ok_or_else(|| PriorError::NotPhysical(model.links()[l].name.clone()))?;
            let gyration = D.iter().map(|&k| theta[k].exp()).sum::<f64>() / 3.0;
            let distance = T.iter().map(|&k| theta[k] * theta[k]).sum::<f64>().sqrt();
            let base = COORDINATES * l;
            for k in 0..COORDINATES {
                mean[base + k] = theta[k];
                std[base + k] = match k {
                    ALPHA => spread.mass / 2.0,
                    // In the independent coordinates: the tensor's scale, then two radii's shape.
                    _ if k == D[0] => spread.inertia / 2.0,
                    _ if D[1..].contains(&k) => SHAPE * spread.inertia / 2.0,
                    _ if S.contains(&k) => spread.inertia / 2.0 * gyration,
                    _ => spread.com * distance.max(0.01),
                };
            }
        }
        for (j, joint) in model.joints().iter().enumerate() {
            let at = COORDINATES * n + NF * j;
            let (effort, speed) = (joint.limits.effort, joint.limits.velocity);
            mean[at] = joint.friction.coulomb;
            mean[at + 1] = joint.friction.viscous;
            std[at] = spread.friction * joint.friction.coulomb.max(TYPICAL_FRICTION.0 * effort);
            std[at + 1] = spread.friction * joint.friction.viscous.max(TYPICAL_FRICTION.1 * effort / speed);
            let (d, d_std) = drive::prior(model, j);
            let at = drive_coordinate(n, j, 0);
            (mean[at], mean[at + 1], std[at], std[at + 1]) = (d.armature, d.offset, d_std.armature, d_std.offset);
        }
        Ok(CoordinatePrior { mean, std, links: n })
    }

    /// This prior with its mean at `mean`, its spreads kept.
    pub fn moved_to(&self, mean: DVector<f64>) -> Self {
        CoordinatePrior { mean, ..self.clone() }
    }

    /// `x - mean` in the independent coordinates, each over its standard deviation: a standard normal vector.
    pub fn whiten(&self, x: &DVector<f64>) -> DVector<f64> {
        self.on_links(x - &self.mean, independent).component_div(&self.std)
    }

    /// The coordinates at standard normal `z` (the inverse of [`CoordinatePrior::whiten`]).
    pub fn colour(&self, z: &DVector<f64>) -> DVector<f64> {
        self.on_links(z.component_mul(&self.std), from_independent) + &self.mean
    }

    /// `v` with `f` applied to every link's mass and radii.
    fn on_links(&self, mut v: DVector<f64>, f: fn([f64; 4]) -> [f64; 4]) -> DVector<f64> {
        for l in 0..self.links {
            let at = mass_and_radii(l);
            for (k, value) in at.iter().zip(f(at.map(|k| v[k]))) {
                v[*k] = value;
            }
        }
        v
    }

    /// The prior's precision matrix over `x` (block diagonal: a link's mass and radii are coupled).
    pub fn precision(&self) -> DMatrix<f64> {
        let map = self.linear(independent);
        map.transpose() * DMatrix::from_diagonal(&self.std.map(|s| 1.0 / (s * s))) * map
    }

    /// The prior's covariance over `x`.
    pub fn covariance(&self) -> DMatrix<f64> {
        let root = self.linear(from_independent) * DMatrix::from_diagonal(&self.std);
        &root * root.transpose()
    }

    /// The prior's standard deviation of each coordinate of `x`.
    pub fn marginal_std(&self) -> DVector<f64> {
        self.covariance().diagonal().map(f64::sqrt)
    }

    /// The matrix of [`CoordinatePrior::on_links`] with `f` (linear): its columns are the unit vectors mapped.
    fn linear(&self, f: fn([f64; 4]) -> [f64; 4]) -> DMatrix<f64> {
        let p = self.mean.len();
        let columns: Vec<DVector<f64>> =
            (0..p).map(|k| self.on_links(DVector::from_fn(p, |r, _| if r == k { 1.0 } else { 0.0 }), f)).collect();
        DMatrix::from_columns(&columns)
    }

    /// A robot drawn from this prior: `model`'s kinematics with each link's inertial at coordinates drawn from
    /// their Gaussians (`normal` gives standard normal numbers) and no friction, as a user's URDF states none. What
    /// a calibration's spreads are tested against: a robot whose truth the prior holds as it claims to.
    pub fn draw(&self, model: &Model, normal: impl FnMut() -> f64) -> Result<Model, PriorError> {
        self.draw_with(model, normal, false)
    }

    /// A member of the robot's family: as [`CoordinatePrior::draw`], and friction drawn too, folded onto the
    /// non-negative values (`|mean + std z|`: about the URDF's value, or within the typical friction of none when it states less).
    pub fn draw_variant(&self, model: &Model, normal: impl FnMut() -> f64) -> Result<Model, PriorError> {
        self.draw_with(model, normal, true)
    }

    fn draw_with(&self, model: &Model, mut normal: impl FnMut() -> f64, friction: bool) -> Result<Model, PriorError> {
        let n = model.dof();
        let z = DVector::from_fn(self.mean.len(), |_, _| normal());
        let mut x = self.colour(&z);
        for k in COORDINATES * n..x.len() {
            x[k] = if friction { x[k].abs() } else { 0.0 };
        }
        drive::with_identified(model, &parameters(n, &x)).map_err(|e| PriorError::NotPhysical(e.to_string()))
    }
}

/// Coordinates per joint (its link's, its friction's, its drive's).
const PER_JOINT: usize = COORDINATES + NF + ND;

/// Length of the coordinate vector of an `n`-joint robot.
pub fn coordinates(n: usize) -> usize {
    n * PER_JOINT
}

/// The joints of a coordinate vector of `len`.
pub fn joints_of(len: usize) -> usize {
    len / PER_JOINT
}

/// The coordinates that are not negative: friction and armature (an offset has either sign).
pub fn non_negative(n: usize) -> impl Iterator<Item = usize> {
    (COORDINATES * n..COORDINATES * n + NF * n).chain((0..n).map(move |j| drive_coordinate(n, j, 0)))
}

/// The identified parameters (`dynforge_proto::params` layout, then the drives': `crate::drive`) at coordinates `x`.
pub fn parameters(n: usize, x: &DVector<f64>) -> Vec<f64> {
    let mut pi = vec![0.0; identified_len(n)];
    for l in 0..n {
        let p = standard::params(&x.as_slice()[COORDINATES * l..COORDINATES * (l + 1)]);
        pi[NI * l..NI * (l + 1)].copy_from_slice(&p);
    }
    pi[NI * n..].copy_from_slice(&x.as_slice()[COORDINATES * n..]);
    pi
}

/// The coordinates of the identified parameters `pi` (the inverse of [`parameters`]), or `None` where a link's are
/// not a physical body.
pub fn coordinates_of(n: usize, pi: &[f64]) -> Option<DVector<f64>> {
    let mut x = DVector::zeros(coordinates(n));
    for l in 0..n {
        let theta = standard::coordinates(&pi[NI * l..NI * (l + 1)])?;
        x.rows_mut(COORDINATES * l, COORDINATES).copy_from_slice(&theta);
    }
    x.rows_mut(COORDINATES * n, (NF + ND) * n).copy_from_slice(&pi[NI * n..]);
    Some(x)
}

/// `d pi / d x`: block diagonal, the links' log-Cholesky Jacobians then the identity of friction and drives.
pub fn jacobian(n: usize, x: &DVector<f64>) -> DMatrix<f64> {
    let mut jac = DMatrix::zeros(identified_len(n), coordinates(n));
    for l in 0..n {
        let block = standard::jacobian(&x.as_slice()[COORDINATES * l..COORDINATES * (l + 1)]);
        for (k, column) in block.iter().enumerate() {
            for (r, v) in column.iter().enumerate() {
                jac[(NI * l + r, COORDINATES * l + k)] = *v;
            }
        }
    }
    for k in 0..(NF + ND) * n {
        jac[(NI * n + k, COORDINATES * n + k)] = 1.0;
    }
    jac
}

/// The index in `x` of link `l`'s coordinate `k`, and of joint `j`'s friction (0 Coulomb, 1 viscous).
pub fn link_coordinate(l: usize, k: usize) -> usize {
    COORDINATES * l + k
}

pub fn friction_coordinate(n: usize, j: usize, which: usize) -> usize {
    COORDINATES * n + NF * j + which
}

/// The index in `x` of joint `j`'s drive term `which` (0 armature, 1 offset).
pub fn drive_coordinate(n: usize, j: usize, which: usize) -> usize {
    (COORDINATES + NF) * n + ND * j + which
}

/// Indices of the centre-of-mass coordinates of link `l` (they are the COM itself).
pub fn com_coordinates(l: usize) -> [usize; 3] {
    T.map(|k| COORDINATES * l + k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generator::generate;
    use crate::rng::Rng;
    use dynforge_proto::generator::GeneratorConfig;

    fn prior() -> (Model, CoordinatePrior) {
        let model = generate(&GeneratorConfig::default(), 3, 1).expect("a generated robot").model;
        let prior = CoordinatePrior::of(&model, Spread::uniform(0.3)).expect("a physical robot");
        (model, prior)
    }

    #[test]
    fn whitening_colouring_precision_and_covariance_agree() {
        let (_, prior) = prior();
        let mut rng = Rng::stream(3, &[]);
        let z = DVector::from_fn(prior.mean.len(), |_, _| rng.normal());
        let back = prior.whiten(&prior.colour(&z));
        assert!((back - &z).amax() < 1e-12);
        // The precision is the covariance's inverse (both built from one map and its inverse).
        let product = prior.precision() * prior.covariance();
        let identity = DMatrix::<f64>::identity(z.len(), z.len());
        assert!((product - identity).amax() < 1e-9);
    }

    /// A spread per kind moves only its kind: the COM's prior narrows with `com=`, the mass's and friction's stay.
    #[test]
    fn a_kind_s_spread_sets_only_that_kind_s_prior() {
        let (model, uniform) = prior();
        let tight = CoordinatePrior::of(&model, "0.3,com=0.1".parse().expect("a spread")).expect("physical");
        let (u, t) = (uniform.marginal_std(), tight.marginal_std());
        let n = model.dof();
        for l in 0..n {
            for k in T.map(|k| COORDINATES * l + k) {
                assert!((t[k] / u[k] - 1.0 / 3.0).abs() < 1e-12, "link {l} COM: {} vs {}", t[k], u[k]);
            }
            assert_eq!(t[COORDINATES * l + ALPHA], u[COORDINATES * l + ALPHA]);
            assert_eq!(t[COORDINATES * l + D[2]], u[COORDINATES * l + D[2]]);
        }
        assert_eq!(t.rows(COORDINATES * n, NF * n), u.rows(COORDINATES * n, NF * n));
    }

    /// Over 4000 draws the sample standard deviation of a normal quantity is within ~1.1 % (1 / sqrt(2 N)) of the
    /// true one; 5 % is over four of those.
    #[test]
    fn draws_hold_mass_scale_and_com_within_their_stated_spreads() {
        let (model, prior) = prior();
        let mut rng = Rng::stream(4, &[]);
        let draws = 4000;
        let (mut log_mass, mut log_scale, mut com) = (Vec::new(), Vec::new(), Vec::new());
        let l = 2;
        for _ in 0..draws {
            let drawn = prior.draw(&model, || rng.normal()).expect("a physical draw");
            let p = &dynamic_parameters(&drawn)[NI * l..NI * (l + 1)];
            let theta = standard::coordinates(p).expect("physical");
            log_mass.push(p[0].ln());
            log_scale.push(2.0 * (theta[ALPHA] + D.iter().map(|&k| theta[k]).sum::<f64>() / 3.0));
            com.push(theta[T[2]]);
        }
        let sd = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
        };
        let theta = standard::coordinates(&dynamic_parameters(&model)[NI * l..NI * (l + 1)]).expect("physical");
        let distance = T.iter().map(|&k| theta[k] * theta[k]).sum::<f64>().sqrt().max(0.01);
        for (what, got, want) in [
            ("log mass", sd(&log_mass), 0.3),
            ("log tensor scale", sd(&log_scale), 0.3),
            ("com z", sd(&com), 0.3 * distance),
        ] {
            assert!((got / want - 1.0).abs() < 0.05, "{what}: sd {got} where {want} is stated");
        }
        // Mass and tensor scale are drawn independently.
        let n = draws as f64;
        let (mm, ms) = (log_mass.iter().sum::<f64>() / n, log_scale.iter().sum::<f64>() / n);
        let cov = log_mass.iter().zip(&log_scale).map(|(a, b)| (a - mm) * (b - ms)).sum::<f64>() / n;
        let corr = cov / (sd(&log_mass) * sd(&log_scale));
        assert!(corr.abs() < 0.07, "mass and tensor scale correlate {corr} (0 within ~4 / sqrt(N))");
    }
}
