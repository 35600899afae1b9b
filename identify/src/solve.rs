//! Linear least squares on the normal equations, restricted to the identifiable directions.

use faer::{Mat, Side};

use nalgebra::{DMatrix, DVector};

use crate::IdentifyError;
use crate::normal::NormalEquations;

/// Eigenvalues of the (Jacobi-scaled) normal matrix below this fraction of the largest one count as unidentifiable:
/// the normal matrix squares the regressor's conditioning, so this keeps directions whose singular value is above
/// 1e-5 of the best-excited one, well clear of the ~1e-16 rounding of the structural null space.
pub const RANK_TOLERANCE: f64 = 1e-10;

/// Squared column norms of the regressor below this fraction of the largest are rounding, not signal: a column
/// `1e-10` of the largest in norm is beyond what double precision distinguishes after the normal equations.
const ZERO_COLUMN: f64 = 1e-20;

/// The classical estimate.
#[derive(Debug, Clone)]
pub struct LeastSquares {
    /// Minimum-norm (in Jacobi-scaled coordinates) parameter vector: exact on the identifiable combinations, zero
    /// on the others. It predicts torques; it is not a physical robot.
    pub pi: Vec<f64>,
    /// Identifiable combinations found (the numerical rank), of `num_params(dof)` parameters.
    pub rank: usize,
    /// The torque noise level the residual implies, `sqrt(rss / (rows - rank))` [N m].
    pub sigma: f64,
}

/// Eigenvectors (columns) and eigenvalues of the symmetric `a`, by faer.
pub(crate) fn eigen(a: &DMatrix<f64>) -> Result<(DMatrix<f64>, Vec<f64>), IdentifyError> {
    let p = a.nrows();
    let m = Mat::<f64>::from_fn(p, p, |i, j| a[(i, j)]);
    let eig = m.self_adjoint_eigen(Side::Lower).map_err(|_| IdentifyError::Decomposition)?;
    let (u, lam) = (eig.U(), eig.S().column_vector());
    Ok((DMatrix::from_fn(p, p, |i, j| u[(i, j)]), (0..p).map(|k| lam[k]).collect()))
}

/// `x = A^+ b` over the eigen-directions of `A` (symmetric, positive semi-definite) above `tolerance` of the
/// largest eigenvalue, and how many there were.
pub(crate) fn pseudo_solve(
    a: &DMatrix<f64>,
    b: &DVector<f64>,
    tolerance: f64,
) -> Result<(DVector<f64>, usize), IdentifyError> {
    let p = a.nrows();
    let (u, lam) = eigen(a)?;
    let largest = lam.iter().fold(0.0f64, |a, &b| a.max(b));
    let mut x = DVector::zeros(p);
    let mut rank = 0;
    for k in 0..p {
        if lam[k].partial_cmp(&(tolerance * largest)) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        rank += 1;
        let proj: f64 = (0..p).map(|i| u[(i, k)] * b[i]).sum::<f64>() / lam[k];
        for i in 0..p {
            x[i] += proj * u[(i, k)];
        }
    }
    Ok((x, rank))
}

/// `x = A^+ b` over the identifiable directions of a normal matrix `A` (symmetric, positive semi-definite), in
/// Jacobi-scaled coordinates (minimum norm there), with its numerical rank. The scaling gives parameters of
/// different units (kg, kg m, kg m^2, N m) comparable columns. A column no torque depends on (e.g. link 2's mcy) is
/// zero only up to rounding (1e-34 of the largest squared norm measured): scaled to unit norm, that rounding would
/// pass for an identifiable direction, so columns under ZERO_COLUMN of the largest squared norm count as zero.
pub(crate) fn scaled_pseudo_solve(a: &DMatrix<f64>, b: &DVector<f64>) -> Result<(DVector<f64>, usize), IdentifyError> {
    let p = a.nrows();
    let largest = (0..p).map(|i| a[(i, i)]).fold(0.0f64, f64::max);
    let d = DVector::from_fn(p, |i, _| if a[(i, i)] > ZERO_COLUMN * largest { 1.0 / a[(i, i)].sqrt() } else { 0.0 });
    let scaled = DMatrix::from_fn(p, p, |i, j| a[(i, j)] * d[i] * d[j]);
    let (x, rank) = pseudo_solve(&scaled, &b.component_mul(&d), RANK_TOLERANCE)?;
    Ok((x.component_mul(&d), rank))
}

/// Least squares on the regressor: the parameters that best predict the recorded torques.
pub fn least_squares(ne: &NormalEquations) -> Result<LeastSquares, IdentifyError> {
    if ne.rows() == 0 {
        return Err(IdentifyError::NoData);
    }
    let (a, b, _) = ne.gram();
    let (x, rank) = scaled_pseudo_solve(&a, &b)?;
    let pi: Vec<f64> = x.iter().copied().collect();
    let sigma = (ne.rss(&pi) / (ne.rows().saturating_sub(rank)).max(1) as f64).sqrt();
    Ok(LeastSquares { pi, rank, sigma })
}
