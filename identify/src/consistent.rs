//! Physically consistent identification: the maximum a posteriori parameters of a robot given its torques, searched
//! over the log-Cholesky coordinates of every link (`crate::standard`: every point a physical body) and non-negative
//! friction, with a Gaussian prior in those coordinates. What the torques determine is fitted as well as least
//! squares fits it; what they cannot see stays at the prior; no projection afterwards moves either.
//!
//! The data term is the weighted residual sum of squares, a quadratic form of the parameters `pi` held by the normal
//! equations (so an iteration costs `O(p^2)`, not a pass over the log); the search is Levenberg-Marquardt on the
//! Gauss-Newton model `pi(x + dx) ~ pi(x) + J dx`, continued from the prior's weight to the data's whole ([`solve`]).
//! The posterior covariance of the coordinates is the inverse of the Gauss-Newton Hessian at the optimum (Laplace).

use dynforge_proto::params::{FRICTION_PARAMS_PER_JOINT as NF, INERTIAL_PARAMS_PER_LINK as NI};
use dynforge_proto::spread::Spread;
use dynforge_robot::Model;
use dynforge_robot::parameters::dynamic_parameters;
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::drive::{self, DRIVE_PER_JOINT as ND, identified_len};
use crate::normal::NormalEquations;
use crate::standard::{self, ALPHA, COORDINATES, D, S, T};

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
    pub fn of(model: &Model, spread: Spread) -> Result<Self, IdentifyError> {
        let n = model.dof();
        let pi = dynamic_parameters(model);
        let mut mean = DVector::zeros(coordinates(n));
        let mut std = DVector::zeros(coordinates(n));
        for l in 0..n {
            let theta = standard::coordinates(&pi[NI * l..NI * (l + 1)])
                .ok_or_else(|| IdentifyError::NotPhysical(model.links()[l].name.clone()))?;
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

    /// `x - mean` in the independent coordinates, each over its standard deviation: a standard normal vector.
    pub fn whiten(&self, x: &DVector<f64>) -> DVector<f64> {
        self.on_links(x - &self.mean, independent).component_div(&self.std)
    }

    /// The coordinates at standard normal `z` (the inverse of [`CoordinatePrior::whiten`]).
    pub(crate) fn colour(&self, z: &DVector<f64>) -> DVector<f64> {
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
    pub fn draw(&self, model: &Model, normal: impl FnMut() -> f64) -> Result<Model, IdentifyError> {
        self.draw_with(model, normal, false)
    }

    /// A member of the robot's family: as [`CoordinatePrior::draw`], and friction drawn too, folded onto the
    /// non-negative values (`|mean + std z|`: about the URDF's value, or within the typical friction of none when it states less).
    pub fn draw_variant(&self, model: &Model, normal: impl FnMut() -> f64) -> Result<Model, IdentifyError> {
        self.draw_with(model, normal, true)
    }

    fn draw_with(
        &self,
        model: &Model,
        mut normal: impl FnMut() -> f64,
        friction: bool,
    ) -> Result<Model, IdentifyError> {
        let n = model.dof();
        let z = DVector::from_fn(self.mean.len(), |_, _| normal());
        let mut x = self.colour(&z);
        for k in COORDINATES * n..x.len() {
            x[k] = if friction { x[k].abs() } else { 0.0 };
        }
        crate::calibrate::model_with(model, &parameters(n, &x))
    }
}

/// Coordinates per joint (its link's, its friction's, its drive's).
const PER_JOINT: usize = COORDINATES + NF + ND;

/// Length of the coordinate vector of an `n`-joint robot.
pub fn coordinates(n: usize) -> usize {
    n * PER_JOINT
}

/// The joints of a coordinate vector of `len`.
fn joints_of(len: usize) -> usize {
    len / PER_JOINT
}

/// The coordinates that are not negative: friction and armature (an offset has either sign).
fn non_negative(n: usize) -> impl Iterator<Item = usize> {
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

/// The weighted data: `G = sum_j w_j Y_j^T Y_j`, `g = sum_j w_j Y_j^T tau_j`, `c = sum_j w_j tau_j^T tau_j`.
struct Data {
    g: DMatrix<f64>,
    rhs: DVector<f64>,
    c: f64,
}

impl Data {
    fn new(ne: &NormalEquations, weights: &[f64]) -> Self {
        let p = ne.columns();
        let (mut g, mut rhs, mut c) = (DMatrix::zeros(p, p), DVector::zeros(p), 0.0);
        for (j, w) in weights.iter().enumerate() {
            let (a, b, cj, _) = ne.joint(j);
            g += a * *w;
            rhs += b * *w;
            c += cj * w;
        }
        Data { g, rhs, c }
    }

    /// The data with every weight times `share`.
    fn scaled(&self, share: f64) -> Self {
        Data { g: &self.g * share, rhs: &self.rhs * share, c: self.c * share }
    }

    /// Half the weighted residual sum of squares of `pi` (infinite where `pi` overflowed: a step too far).
    fn cost(&self, pi: &DVector<f64>) -> f64 {
        let rss = pi.dot(&(&self.g * pi)) - 2.0 * self.rhs.dot(pi) + self.c;
        if rss.is_finite() { 0.5 * rss.max(0.0) } else { f64::INFINITY }
    }
}

/// Where the search ended.
#[derive(Debug, Clone)]
pub struct Solution {
    pub x: DVector<f64>,
    /// The objective at `x` (half the weighted residual sum of squares plus half the prior's squared distance).
    pub cost: f64,
    /// Posterior covariance of `x` (Laplace, at the optimum).
    pub covariance: DMatrix<f64>,
    pub iterations: usize,
    pub converged: bool,
}

/// Most iterations of one stage of the search before giving up; a stage converges in tens.
pub const MAX_ITERATIONS: usize = 500;

/// Relative decrease of the objective under which the search has converged.
const TOLERANCE: f64 = 1e-11;

/// Growth of the data's weight from one stage of the continuation to the next.
const CONTINUATION_STEP: f64 = 10.0;

/// The MAP coordinates for the normal equations `ne`, each joint's rows weighted by `weights` (its inverse noise
/// variance), under `prior`, searched from `start` by continuation in the data's weight.
///
/// The torques of a clean log pin the identifiable combinations to a part in 10^5 or better, so in the coordinates
/// the optimum lies at the bottom of a valley that narrow and curved (the log-Cholesky map bends it): searched at
/// full weight from a description tens of percent off, Levenberg-Marquardt crawls along it and stops at its iteration
/// limit with torques left unexplained, and the Laplace spreads of such a point are far too narrow (a generated UR5
/// from four logs: 2e-4 of the torque unexplained, an inertia written at 0.133 against 0.303 with a spread of 9e-5;
/// seven of ten such variants stopped so). The search starts instead with the data weighed as much as the prior
/// (their costs at `start` equal) and multiplies the weight by [`CONTINUATION_STEP`] per stage up to the whole: each
/// stage's optimum is close to the next's, the MAP's path from the prior to the data is followed, and a few hundred
/// iterations in all reach the optimum that the search at full weight does not reach in thousands.
pub fn solve(
    ne: &NormalEquations,
    weights: &[f64],
    prior: &CoordinatePrior,
    start: &DVector<f64>,
) -> Result<Solution, IdentifyError> {
    follow(&Data::new(ne, weights), prior, start, (TOLERANCE, TOLERANCE))
}

/// [`solve`] on the weighted data `data`, its stages before the last converged to a relative decrease of `stages`,
/// the last to `last`.
fn follow(
    data: &Data,
    prior: &CoordinatePrior,
    start: &DVector<f64>,
    (stages, last): (f64, f64),
) -> Result<Solution, IdentifyError> {
    let at_start = data.cost(&DVector::from_vec(parameters(joints_of(start.len()), start)));
    // A start the data cannot even score (overflowed) is searched at full weight.
    let mut share = if at_start.is_finite() { start.len() as f64 / at_start } else { 1.0 };
    let (mut x, mut iterations) = (start.clone(), 0);
    while share < 1.0 {
        let stage = search(&data.scaled(share), prior, &x, stages)?;
        (x, iterations) = (stage.x, iterations + stage.iterations);
        share *= CONTINUATION_STEP;
    }
    let last = search(data, prior, &x, last)?;
    Ok(Solution { iterations: iterations + last.iterations, ..last })
}

/// Levenberg-Marquardt from `start` on the data `data` under `prior`.
fn search(
    data: &Data,
    prior: &CoordinatePrior,
    start: &DVector<f64>,
    tolerance: f64,
) -> Result<Solution, IdentifyError> {
    let n = joints_of(start.len());
    let precision = prior.precision();
    let scale = prior.marginal_std();
    let objective = |x: &DVector<f64>| posterior_cost(data, prior, x, &DVector::from_vec(parameters(n, x)));
    let mut x = start.clone();
    let mut f = objective(&x);
    let mut lambda = 1e-3;
    let (mut iterations, mut converged) = (0, false);
    while iterations < MAX_ITERATIONS && !converged {
        iterations += 1;
        let pi = DVector::from_vec(parameters(n, &x));
        let jac = jacobian(n, &x);
        let mut grad = jac.transpose() * (&data.g * &pi - &data.rhs) + &precision * (&x - &prior.mean);
        let mut hessian = jac.transpose() * &data.g * &jac + &precision;
        // A coordinate at its bound that the objective pushes past it is held there (an active set): stepped and
        // then clamped, it would shorten every step of the others and the search would crawl (an arm without rotor
        // inertia, identified with it, ends with its armature at zero).
        let held: Vec<usize> = non_negative(n).filter(|&k| x[k] <= 0.0 && grad[k] > 0.0).collect();
        for k in held {
            grad[k] = 0.0;
            hessian.row_mut(k).fill(0.0);
            hessian.column_mut(k).fill(0.0);
            hessian[(k, k)] = 1.0;
        }
        let scaled = Scaled::new(&hessian);
        loop {
            let mut next = &x - scaled.solve(&grad, lambda)?;
            for k in non_negative(n) {
                next[k] = next[k].max(0.0);
            }
            let f_next = objective(&next);
            if f_next <= f {
                // Converged when the objective stops falling, or the step is nothing on the prior's scale.
                let step = (&next - &x).component_div(&scale).amax();
                converged = f - f_next <= tolerance * f.max(1.0) || step < 1e-9;
                x = next;
                f = f_next;
                lambda = (lambda / 3.0).max(1e-12);
                break;
            }
            lambda *= 4.0;
            if lambda > 1e12 {
                converged = true;
                break;
            }
        }
    }
    let jac = jacobian(n, &x);
    let hessian = jac.transpose() * &data.g * &jac + &precision;
    let covariance = Scaled::new(&hessian).inverse()?;
    Ok(Solution { x, cost: f, covariance, iterations, converged })
}

/// Prior draws the search also starts from, besides the description ([`optima`]).
pub const STARTS: usize = 8;

/// Relative decrease of the objective at which a start's path under its moved prior is followed far enough: the
/// search under the prior itself that ends it converges to [`TOLERANCE`].
const ROUGH: f64 = 1e-6;

/// Seed of the starts' draws: the same for every calibration, so that the same logs give the same URDF.
const START_SEED: u64 = 0x0005_eed0_f0a7;

/// Objective above the best optimum's beyond which an optimum's share of the posterior (`exp(-gap)`) is nothing.
pub const NEGLIGIBLE_GAP: f64 = 20.0;

/// The optima the searches from the description and from prior draws end at.
#[derive(Debug, Clone)]
pub struct Optima {
    /// The optimum of lowest objective: the MAP.
    pub best: Solution,
    /// `sum_k w_k d_k d_k^T`, `d_k` each optimum's distance from the best and `w_k` its share of the posterior
    /// (`exp(-objective)`, normalized over the optima): what a spread about the best must add for the
    /// others.
    pub between: DMatrix<f64>,
    /// Objective gap of every other optimum that has a share (under [`NEGLIGIBLE_GAP`]), lowest first.
    pub gaps: Vec<f64>,
}

/// The MAP among the optima that searches from `found`'s start and from [`STARTS`] draws of the prior reach (each by
/// continuation, as [`solve`] searches), and the spread the others add.
///
/// The posterior can have more than one optimum within a unit or two of the objective: the UR5's forearm COM and the
/// mass of the wrist at its far end trade along a first moment the torques see, and a URDF whose COM prior is wide
/// (a COM stated far from the joint) lets the search from it end with the COM at the joint and the wrist twice as
/// heavy, or at the truth (measured in docs/notes.md). A Laplace spread at either optimum is a twentieth of the
/// distance between them. Searches from draws of the prior find the others; the lowest objective is the MAP, and
/// each other end that the way to every optimum kept so far leaves by rising ([`BARRIER`]) is an optimum, which adds
/// its distance, weighted by its share, to the spread.
pub fn optima(
    ne: &NormalEquations,
    weights: &[f64],
    prior: &CoordinatePrior,
    found: Solution,
) -> Result<Optima, IdentifyError> {
    let links = ne.dof();
    let draws: Vec<CoordinatePrior> = (0..STARTS as u64)
        .map(|k| {
            let mut rng = dynforge_robot::rng::Rng::stream(START_SEED, &[k]);
            let mut mean = prior.colour(&DVector::from_fn(prior.mean.len(), |_, _| rng.normal()));
            for k in non_negative(links) {
                mean[k] = mean[k].max(0.0);
            }
            CoordinatePrior { mean, ..prior.clone() }
        })
        .collect();
    // Each start is the MAP under the prior moved to a draw of itself, then searched under the prior itself: a
    // continuation under the prior itself from a draw follows the prior's pull back to the path from its mean and
    // ends where that does. A start from which the way to the description's optimum only descends is in its basin
    // and is not searched on; a start the search cannot follow (a draw far in the prior's tail) is one fewer.
    let objective = Objective { data: Data::new(ne, weights), prior, links };
    let ends = dynforge_proto::parallel::map_in_order(&draws, |moved| {
        let start = follow(&objective.data, moved, &moved.mean, (ROUGH, ROUGH)).ok()?;
        if objective.barrier(&start.x, &found.x) <= BARRIER {
            return None;
        }
        follow(&objective.data, prior, &start.x, (ROUGH, TOLERANCE)).ok()
    });
    let mut all: Vec<Solution> = std::iter::once(found).chain(ends.into_iter().flatten()).collect();
    all.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let best = all.swap_remove(0);
    let mut others: Vec<Solution> = Vec::new();
    for s in all.into_iter().filter(|s| s.cost - best.cost < NEGLIGIBLE_GAP) {
        if std::iter::once(&best).chain(&others).all(|o| objective.barrier(&s.x, &o.x) > BARRIER) {
            others.push(s);
        }
    }
    let total: f64 = 1.0 + others.iter().map(|s| (best.cost - s.cost).exp()).sum::<f64>();
    let mut between = DMatrix::zeros(best.x.len(), best.x.len());
    for s in &others {
        let d = &s.x - &best.x;
        between += (&d * d.transpose()) * ((best.cost - s.cost).exp() / total);
    }
    let gaps = others.iter().map(|s| s.cost - best.cost).collect();
    Ok(Optima { best, between, gaps })
}

/// Rise of the objective above a search's end on the way to another optimum beyond which the end is an optimum of
/// its own.
const BARRIER: f64 = 0.05;

/// Points of the way from one search's end to another optimum at which the objective is evaluated.
const WAY: usize = 32;

/// The MAP's objective, as a function of the parameters.
struct Objective<'a> {
    data: Data,
    prior: &'a CoordinatePrior,
    links: usize,
}

impl Objective<'_> {
    /// The highest objective on the straight way in the parameters from `end` to `other`, over `end`'s own (both
    /// coordinates).
    ///
    /// A search's end is an optimum of its own only if the way to the other rises first. The torques are a linear
    /// function of the parameters, so in them the data's valley is straight and the way stays on its floor (and
    /// every point of it is a physical body: the set is convex); in the coordinates the same valley is curved and
    /// narrow enough on a clean log that the search stops on its wall, a unit or less of objective above the
    /// optimum it was still crawling toward, looking like another optimum to every local test.
    fn barrier(&self, end: &DVector<f64>, other: &DVector<f64>) -> f64 {
        let (a, b) = (parameters(self.links, end), parameters(self.links, other));
        let Some(at_end) = self.at(&a) else { return f64::INFINITY };
        (1..WAY)
            .map(|k| {
                let t = k as f64 / WAY as f64;
                let pi: Vec<f64> = a.iter().zip(&b).map(|(a, b)| a + t * (b - a)).collect();
                self.at(&pi).map_or(f64::INFINITY, |f| f - at_end)
            })
            .fold(f64::NEG_INFINITY, f64::max)
    }

    /// The objective at the parameters `pi` (`None` where a link's are not a physical body).
    fn at(&self, pi: &[f64]) -> Option<f64> {
        let n = self.links;
        let mut x = DVector::zeros(coordinates(n));
        for l in 0..n {
            let theta = standard::coordinates(&pi[NI * l..NI * (l + 1)])?;
            x.rows_mut(COORDINATES * l, COORDINATES).copy_from_slice(&theta);
        }
        x.rows_mut(COORDINATES * n, (NF + ND) * n).copy_from_slice(&pi[NI * n..]);
        Some(posterior_cost(&self.data, self.prior, &x, &DVector::from_column_slice(pi)))
    }
}

/// The objective every search minimizes and every optimum is compared by: the data's cost at the parameters `pi`
/// plus half the whitened prior distance of their coordinates `x` (the same point twice over, so that neither map
/// is made again where the caller has both).
fn posterior_cost(data: &Data, prior: &CoordinatePrior, x: &DVector<f64>, pi: &DVector<f64>) -> f64 {
    let z = prior.whiten(x);
    data.cost(pi) + 0.5 * z.dot(&z)
}

/// A symmetric positive definite matrix `H` as `D S D` with `D = diag(H)^-1/2` (unit diagonal `S`): the torques and
/// the prior weigh coordinates over twenty orders of magnitude, which a Cholesky factor of `H` itself does not
/// survive. `S`'s eigen-decomposition, exact to rounding of its unit scale, is made when needed: for `H^-1`, and for
/// a step whose `S + lambda I` rounding leaves without a Cholesky factor.
struct Scaled {
    d: DVector<f64>,
    s: DMatrix<f64>,
    eigen: std::cell::OnceCell<(DMatrix<f64>, Vec<f64>)>,
}

impl Scaled {
    fn new(h: &DMatrix<f64>) -> Self {
        let d = DVector::from_fn(h.nrows(), |i, _| 1.0 / h[(i, i)].max(f64::MIN_POSITIVE).sqrt());
        let s = DMatrix::from_fn(h.nrows(), h.ncols(), |i, j| h[(i, j)] * d[i] * d[j]);
        Scaled { d, s, eigen: std::cell::OnceCell::new() }
    }

    /// `S`'s eigenvectors and eigenvalues, the eigenvalues held above rounding (`1e-15` of the largest).
    fn eigen(&self) -> Result<&(DMatrix<f64>, Vec<f64>), IdentifyError> {
        if self.eigen.get().is_none() {
            let (vectors, mut values) = crate::solve::eigen(&self.s)?;
            let top = values.iter().fold(0.0f64, |m, v| m.max(*v));
            values.iter_mut().for_each(|v| *v = v.max(1e-15 * top));
            // Unset until now, so this cannot fail.
            let _ = self.eigen.set((vectors, values));
        }
        Ok(self.eigen.get().expect("the decomposition was just made"))
    }

    /// `(H + lambda diag(H))^-1 g`: the scaled matrix gains `lambda` on its (unit) diagonal. A Cholesky solve (a
    /// tenth of a decomposition's work: the search makes one or more per iteration, eight starts over), or the
    /// decomposition's.
    fn solve(&self, g: &DVector<f64>, lambda: f64) -> Result<DVector<f64>, IdentifyError> {
        let rhs = g.component_mul(&self.d);
        let shifted = &self.s + DMatrix::from_diagonal_element(self.s.nrows(), self.s.ncols(), lambda);
        if let Some(c) = shifted.cholesky() {
            return Ok(c.solve(&rhs).component_mul(&self.d));
        }
        let (vectors, values) = self.eigen()?;
        let proj = vectors.transpose() * rhs;
        let y = DVector::from_fn(proj.len(), |k, _| proj[k] / (values[k] + lambda));
        Ok((vectors * y).component_mul(&self.d))
    }

    /// `H^-1`.
    fn inverse(&self) -> Result<DMatrix<f64>, IdentifyError> {
        let (vectors, values) = self.eigen()?;
        let inv = DVector::from_iterator(values.len(), values.iter().map(|v| 1.0 / v));
        let s_inv = vectors * DMatrix::from_diagonal(&inv) * vectors.transpose();
        Ok(DMatrix::from_fn(s_inv.nrows(), s_inv.ncols(), |i, j| s_inv[(i, j)] * self.d[i] * self.d[j]))
    }
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
    use dynforge_robot::generator::{GeneratorConfig, generate};
    use dynforge_robot::rng::Rng;

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
