//! The samples of a recording that identification and the torque check use.

/// Joint speed [rad/s] under which a joint's torque is left out of a sample: at rest, Coulomb friction is static
/// and takes any value in `[-mu_c, mu_c]`, so no parameter set predicts it.
pub const REST_SPEED: f64 = 1e-2;

/// A recording on a uniform time grid: per sample, `dof` values of position, velocity and applied torque.
#[derive(Debug, Clone, Copy)]
pub struct Recording<'a> {
    pub q: &'a [f64],
    pub qd: &'a [f64],
    pub tau: &'a [f64],
    pub dof: usize,
    /// Grid step [s].
    pub dt: f64,
}

impl Recording<'_> {
    /// Samples in the recording.
    pub fn len(&self) -> usize {
        self.q.len() / self.dof.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Calls `f(q, qd, qdd, tau)` for every interior sample, with `qdd` by central differences of `qd`. On data
    /// integrated at the grid step with the torque held over each step, the central difference is the
    /// acceleration consistent with the integration scheme to `O(dt^2)`.
    pub(crate) fn for_each(&self, mut f: impl FnMut(&[f64], &[f64], &[f64], &[f64])) {
        let n = self.dof;
        let mut qdd = vec![0.0; n];
        for i in 1..self.len().saturating_sub(1) {
            let r = i * n..(i + 1) * n;
            for (j, a) in qdd.iter_mut().enumerate() {
                *a = (self.qd[r.start + n + j] - self.qd[r.start - n + j]) / (2.0 * self.dt);
            }
            f(&self.q[r.clone()], &self.qd[r.clone()], &qdd, &self.tau[r]);
        }
    }
}
