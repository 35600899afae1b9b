//! Physically consistent identification: the maximum a posteriori parameters of a robot given its torques, searched
//! over the log-Cholesky coordinates of every link (`dynforge_robot::prior`: every point a physical body) and non-negative
//! friction, with a Gaussian prior in those coordinates. What the torques determine is fitted as well as least
//! squares fits it; what they cannot see stays at the prior; no projection afterwards moves either.
//!
//! The data term is the weighted residual sum of squares, a quadratic form of the parameters `pi` held by the normal
//! equations (so an iteration costs `O(p^2)`, not a pass over the log); the search is Levenberg-Marquardt on the
//! Gauss-Newton model `pi(x + dx) ~ pi(x) + J dx`, continued from the prior's weight to the data's whole ([`solve`]).
//! The posterior covariance of the coordinates is the inverse of the Gauss-Newton Hessian at the optimum (Laplace).

use dynforge_robot::prior::{CoordinatePrior, coordinates_of, jacobian, joints_of, non_negative, parameters};
use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::normal::NormalEquations;

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
/// heavy, or at the truth (measured in docs/identification.md). A Laplace spread at either optimum is a twentieth of the
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
            prior.moved_to(mean)
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
        let x = coordinates_of(self.links, pi)?;
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
