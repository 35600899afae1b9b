//! What an identification found, per parameter: value, standard deviation, the URDF's value and the prior's
//! spread, and what decided it.

use dynforge_proto::params::{INERTIAL_PARAMS_PER_LINK as NI, friction_index};
use dynforge_recording::log::Log;
use dynforge_robot::Model;
use dynforge_robot::parameters::dynamic_parameters;
use nalgebra::{DMatrix, Matrix3};

use crate::consistent::Solution;
use crate::normal::NormalEquations;
use crate::signals::{EffortConvention, VelocityChoice, VelocitySource, effort_scatter};
use crate::solve::LeastSquares;
use dynforge_robot::drive::{Drive, identified};
use dynforge_robot::prior::{CoordinatePrior, drive_coordinate, friction_coordinate, link_coordinate};
use dynforge_robot::spatial::log_cholesky::{self as standard, COORDINATES};

/// What decided a parameter: the torques (its posterior spread is under half the prior's) or, when the logs cannot
/// tell it, the prior (the URDF's value).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Decided {
    Torques,
    Prior,
}

/// Posterior spread under this share of the prior's counts as decided by the torques.
pub const INFORMED: f64 = 0.5;

/// What a standard deviation is of: the parameter itself, or its natural logarithm (a mass, which the prior
/// believes to within a factor: its error is log-normal, and a spread in kilograms cannot hold at one and at two
/// standard deviations both).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scale {
    Linear,
    Log,
}

/// One identified parameter.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Estimated {
    pub value: f64,
    /// Posterior standard deviation, of the value or of its logarithm (`scale`).
    pub std: f64,
    /// The URDF's value and the prior's standard deviation (same scale).
    pub urdf: f64,
    pub prior_std: f64,
    pub decided: Decided,
    pub scale: Scale,
    /// For a joint's friction and offset, which change from run to run of the arm (temperature, lubricant): the
    /// standard deviation of the arm's value over runs, `std` and the runs' scatter ([`Identification::over_runs`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub over_runs: Option<f64>,
}

impl Estimated {
    fn new(value: f64, std: f64, urdf: f64, prior_std: f64) -> Self {
        let decided = if std < INFORMED * prior_std { Decided::Torques } else { Decided::Prior };
        Estimated { value, std, urdf, prior_std, decided, scale: Scale::Linear, over_runs: None }
    }

    /// A positive parameter from its linear spreads: the spreads of its logarithm, `std / value` (the delta
    /// method; the log-Cholesky coordinates it is a function of are what the posterior is Gaussian in).
    fn positive(value: f64, std: f64, urdf: f64, prior_std: f64) -> Self {
        let linear = Estimated::new(value, std, urdf, prior_std);
        Estimated { std: std / value, prior_std: prior_std / urdf, scale: Scale::Log, ..linear }
    }

    /// How many standard deviations the value lies from `truth`, on its scale.
    pub fn z(&self, truth: f64) -> f64 {
        match self.scale {
            Scale::Linear => (self.value - truth) / self.std,
            Scale::Log => (self.value / truth).ln() / self.std,
        }
    }
}

/// What a parameter is, for reporting per kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    Mass,
    Com,
    Inertia,
    Friction,
}

impl Kind {
    pub const ALL: [Kind; 4] = [Kind::Mass, Kind::Com, Kind::Inertia, Kind::Friction];

    /// The kind of the parameter named `LINK.field` or `JOINT.field` (as [`Identification::parameters`] names them).
    pub fn of(name: &str) -> Kind {
        match name.rsplit('.').next().unwrap_or_default() {
            "mass" => Kind::Mass,
            "coulomb" | "viscous" => Kind::Friction,
            f if f.starts_with("com") => Kind::Com,
            _ => Kind::Inertia,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Kind::Mass => "mass",
            Kind::Com => "com",
            Kind::Inertia => "inertia",
            Kind::Friction => "friction",
        }
    }
}

/// One reported parameter, named as the family's labels are.
#[derive(Debug, Clone)]
pub struct Parameter<'a> {
    pub name: String,
    pub kind: Kind,
    pub estimate: &'a Estimated,
}

/// A moving link's parameters in its URDF frame: mass [kg], centre of mass [m], inertia about the COM in the
/// link's axes `[ixx, ixy, ixz, iyy, iyz, izz]` [kg m^2] (the link's own and its welded links', as a loader sums
/// them).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LinkEstimate {
    pub name: String,
    pub mass: Estimated,
    pub com: [Estimated; 3],
    pub inertia: [Estimated; 6],
}

/// A joint's friction (N m, N m s/rad; prismatic: N, N s/m), its drive's terms (`crate::drive`: kg m^2 and N m;
/// prismatic: kg and N) and what its torques showed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointEstimate {
    pub name: String,
    pub prismatic: bool,
    pub coulomb: Estimated,
    pub viscous: Estimated,
    pub armature: Estimated,
    pub offset: Estimated,
    /// The torque noise its residual shows [N m or N], and the residual's integrated autocorrelation time [samples].
    pub noise: f64,
    pub correlation: f64,
    /// Torque NRMSE of the calibrated robot on the logs, and the noise floor the raw effort shows (its
    /// high-frequency scatter, through the conditioning), both relative to the torque's spread.
    pub nrmse: f64,
    pub noise_floor: f64,
    /// The share of the residual's variance that is a function of the joint's velocity: near 1, friction the joint
    /// model does not hold; near 0, noise or an error that depends on the rest of the motion.
    pub velocity_share: f64,
}

/// A calibration of a URDF to logs.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Identification {
    pub logs: Vec<String>,
    pub samples: usize,
    /// Torque rows (moving joint samples) used.
    pub rows: usize,
    /// The logs' sampling rate [Hz].
    pub rate: f64,
    pub velocity: VelocityChoice,
    pub effort: EffortConvention,
    pub effort_reason: String,
    /// Identifiable parameter combinations in the logs, of the full parameter vector's `parameters`.
    pub rank: usize,
    pub parameters: usize,
    /// Torque NRMSE on the logs of the URDF as given, of least squares (base parameters) and of the calibration.
    pub nrmse_urdf: f64,
    pub nrmse_least_squares: f64,
    pub nrmse_calibrated: f64,
    pub links: Vec<LinkEstimate>,
    pub joints: Vec<JointEstimate>,
    pub iterations: usize,
    pub converged: bool,
    /// What the user must look at: joints whose torque the calibrated robot leaves far above its noise, and why.
    pub warnings: Vec<String>,
    /// The share friction moves by between runs that the spreads over runs take ([`Identification::over_runs`]).
    pub run_to_run: f64,
    pub notes: Vec<String>,
    /// The least-squares estimate (base parameters, minimum norm): not a robot, a reference for torque prediction.
    #[serde(skip)]
    pub least_squares: Vec<f64>,
    /// The calibrated robot.
    #[serde(skip)]
    pub model: Model,
}

/// What [`Identification::new`] reads.
pub(crate) struct Fitted<'a> {
    pub model: &'a Model,
    pub calibrated: Model,
    pub ne: &'a NormalEquations,
    pub ls: &'a LeastSquares,
    pub prior: &'a CoordinatePrior,
    pub solution: &'a Solution,
    /// The Laplace covariance at the solution (plus the other optima's spread), beside the solution's own (the
    /// sandwich's): a link's spreads are the larger of the two ([`Identification::new`]).
    pub laplace: &'a DMatrix<f64>,
    pub noise: Vec<f64>,
    pub correlation: Vec<f64>,
    pub velocity_share: Vec<f64>,
    pub convention: EffortConvention,
    pub logs: &'a [Log],
    /// What conditioning does to white effort noise ([`crate::signals::noise_gain`]).
    pub noise_gain: f64,
}

/// A link's reported parameters `(mass, com, inertia about the COM in link axes)` at coordinates `theta`.
fn reported(theta: &[f64]) -> [f64; 10] {
    let (m, c, i) = standard::standard(&standard::params(theta), &Matrix3::identity());
    [m, c[0], c[1], c[2], i[0], i[1], i[2], i[3], i[4], i[5]]
}

/// Standard deviations of a link's reported parameters for a covariance `cov` of its coordinates at `theta`
/// (delta method, the derivative by central differences).
fn reported_std(theta: &[f64], cov: &DMatrix<f64>) -> [f64; 10] {
    let h = 1e-6;
    let mut jac = DMatrix::zeros(10, COORDINATES);
    for k in 0..COORDINATES {
        let (mut up, mut down) = (theta.to_vec(), theta.to_vec());
        up[k] += h;
        down[k] -= h;
        let (a, b) = (reported(&up), reported(&down));
        for r in 0..10 {
            jac[(r, k)] = (a[r] - b[r]) / (2.0 * h);
        }
    }
    let c = &jac * cov * jac.transpose();
    std::array::from_fn(|r| c[(r, r)].max(0.0).sqrt())
}

/// A link's reported standard deviations at `theta`: the larger of the sandwich's (`sandwich`) and the Laplace
/// covariance's (`laplace`), each parameter on its own. The sandwich's meat is measured from a few hundred blocks of
/// the residual, and a covariance measured so is too small in some directions by its own sampling error (the Panda's
/// noisy inertias: 2 points within two standard deviations, docs/identification.md); where the model's covariance is wider,
/// it is kept. Friction is not a link's: there the sandwich is what corrects for a coloured residual.
fn link_std(theta: &[f64], sandwich: &DMatrix<f64>, laplace: &DMatrix<f64>) -> [f64; 10] {
    let (s, l) = (reported_std(theta, sandwich), reported_std(theta, laplace));
    std::array::from_fn(|k| s[k].max(l[k]))
}

impl Identification {
    pub(crate) fn new(f: Fitted) -> Self {
        let n = f.model.dof();
        let x = &f.solution.x;
        let prior_cov = f.prior.covariance();
        let block = |c: &DMatrix<f64>, l: usize| {
            c.view((COORDINATES * l, COORDINATES * l), (COORDINATES, COORDINATES)).into_owned()
        };
        let nominal = dynamic_parameters(f.model);
        let links = (0..n)
            .map(|l| {
                let theta = &x.as_slice()[link_coordinate(l, 0)..link_coordinate(l + 1, 0)];
                let theta0 = &f.prior.mean.as_slice()[link_coordinate(l, 0)..link_coordinate(l + 1, 0)];
                let (value, urdf) = (reported(theta), reported(theta0));
                let std = link_std(theta, &block(&f.solution.covariance, l), &block(f.laplace, l));
                let prior_std = reported_std(theta0, &block(&prior_cov, l));
                let e = |k: usize| Estimated::new(value[k], std[k], urdf[k], prior_std[k]);
                LinkEstimate {
                    name: f.model.links()[l].name.clone(),
                    mass: Estimated::positive(value[0], std[0], urdf[0], prior_std[0]),
                    com: [e(1), e(2), e(3)],
                    inertia: [e(4), e(5), e(6), e(7), e(8), e(9)],
                }
            })
            .collect();
        // Friction and the drives' terms are their coordinates themselves.
        let std = |k: usize| f.solution.covariance[(k, k)].sqrt();
        let drive = |j: usize, which: usize| x[drive_coordinate(n, j, which)];
        let drive_values: Vec<Drive> = (0..n).map(|j| Drive { armature: drive(j, 0), offset: drive(j, 1) }).collect();
        let pi = identified(&dynamic_parameters(&f.calibrated), &drive_values);
        let nrmse = f.ne.nrmse(&pi);
        let segments: Vec<&dynforge_recording::JointTrajectory> = f.logs.iter().flat_map(|l| &l.segments).collect();
        let floors: Vec<f64> = effort_scatter(&segments).iter().map(|s| f.noise_gain * s).collect();
        let joints = (0..n)
            .map(|j| {
                let e = |which: usize| {
                    let k = friction_coordinate(n, j, which);
                    let at = friction_index(n, j) + which;
                    Estimated::new(pi[at], std(k), nominal[at], prior_cov[(k, k)].sqrt())
                };
                let d = |which: usize| {
                    let k = drive_coordinate(n, j, which);
                    Estimated::new(drive(j, which), std(k), f.prior.mean[k], prior_cov[(k, k)].sqrt())
                };
                JointEstimate {
                    name: f.model.joints()[j].name.clone(),
                    prismatic: f.model.is_prismatic(j),
                    coulomb: e(0),
                    viscous: e(1),
                    armature: d(0),
                    offset: d(1),
                    noise: f.noise[j],
                    correlation: f.correlation[j],
                    nrmse: nrmse[j],
                    noise_floor: floors[j],
                    velocity_share: f.velocity_share[j],
                }
            })
            .collect();
        let samples = f.logs.iter().map(Log::samples).sum();
        Identification {
            logs: f.logs.iter().map(Log::name).collect(),
            samples,
            rows: f.ne.rows(),
            rate: 1.0 / f.logs[0].dt,
            velocity: VelocityChoice { source: VelocitySource::Logged, cutoff: None, step: 1, reason: String::new() },
            effort: f.convention,
            effort_reason: String::new(),
            rank: f.ls.rank,
            parameters: f.ne.columns(),
            nrmse_urdf: f.ne.mean_nrmse(&nominal),
            nrmse_least_squares: f.ne.mean_nrmse(&f.ls.pi),
            nrmse_calibrated: f.ne.mean_nrmse(&pi),
            links,
            joints,
            iterations: f.solution.iterations,
            converged: f.solution.converged,
            warnings: Vec::new(),
            run_to_run: 0.0,
            notes: Vec::new(),
            least_squares: f.ls.pi.clone(),
            model: f.calibrated,
        }
    }

    /// The values of `model` (the calibrated robot as written and read back) in place of the calibration's, so that
    /// what is reported is what the file holds, to the last digit.
    pub fn report_values_of(&mut self, model: &Model) {
        let pi = dynamic_parameters(model);
        let n = model.dof();
        for (l, link) in self.links.iter_mut().enumerate() {
            let p: [f64; NI] = pi[NI * l..NI * (l + 1)].try_into().expect("10 parameters per link");
            let (m, c, i) = standard::standard(&p, &Matrix3::identity());
            link.mass.value = m;
            link.com.iter_mut().zip(c).for_each(|(e, v)| e.value = v);
            link.inertia.iter_mut().zip(i).for_each(|(e, v)| e.value = v);
        }
        for (j, joint) in self.joints.iter_mut().enumerate() {
            joint.coulomb.value = pi[friction_index(n, j)];
            joint.viscous.value = pi[friction_index(n, j) + 1];
        }
        self.model = model.clone();
    }

    /// Each joint's drive terms as identified (the URDF holds none).
    pub fn drives(&self) -> Vec<Drive> {
        self.joints.iter().map(|j| Drive { armature: j.armature.value, offset: j.offset.value }).collect()
    }

    /// The identified vector of the calibrated robot: its parameters (as [`Identification::model`] holds them) and
    /// its drives'.
    pub fn identified(&self) -> Vec<f64> {
        identified(&dynamic_parameters(&self.model), &self.drives())
    }

    /// Parameters the prior decided (the logs could not tell them), by name.
    pub fn from_prior(&self) -> Vec<String> {
        self.parameters().into_iter().filter(|p| p.estimate.decided == Decided::Prior).map(|p| p.name).collect()
    }

    /// Every reported parameter in order (each link's mass, COM, inertia; then each joint's Coulomb and viscous
    /// friction), named `LINK.mass` .. `JOINT.viscous` as the family's labels are.
    pub fn parameters(&self) -> Vec<Parameter<'_>> {
        let mut out = Vec::new();
        for l in &self.links {
            let named = [("mass", &l.mass)]
                .into_iter()
                .chain(["com_x", "com_y", "com_z"].into_iter().zip(&l.com))
                .chain(["ixx", "ixy", "ixz", "iyy", "iyz", "izz"].into_iter().zip(&l.inertia));
            out.extend(named.map(|(k, estimate)| Parameter {
                name: format!("{}.{k}", l.name),
                kind: Kind::of(k),
                estimate,
            }));
        }
        for j in &self.joints {
            for (k, estimate) in [("coulomb", &j.coulomb), ("viscous", &j.viscous)] {
                out.push(Parameter { name: format!("{}.{k}", j.name), kind: Kind::Friction, estimate });
            }
        }
        out
    }

    /// The estimates of [`Identification::parameters`], in the same order, to change their spreads.
    pub fn estimates_mut(&mut self) -> impl Iterator<Item = &mut Estimated> {
        let links =
            self.links.iter_mut().flat_map(|l| std::iter::once(&mut l.mass).chain(&mut l.com).chain(&mut l.inertia));
        links.chain(self.joints.iter_mut().flat_map(|j| [&mut j.coulomb, &mut j.viscous]))
    }
}

/// How far a joint's friction moves from one run of the arm to the next, as a share of its value (and its offset,
/// as a share of its Coulomb friction): between the real UR10e's four logs of three days, the scatter beyond each
/// log's own spreads was 0.7-9.5 % of the value (median 4 %) for Coulomb and viscous friction and 0-5 % of Coulomb
/// friction for the offsets (docs/measurements.md). An assumption for other arms: `--run-to-run`.
pub const RUN_TO_RUN: f64 = 0.05;

/// Where the run-to-run share comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RunToRun {
    /// This share.
    Share(f64),
    /// Measured over the logs when there are several ([`measured_share`], each log identified alone), else
    /// [`RUN_TO_RUN`].
    Measured,
}

/// The share friction moves by between runs, from identifications of one run each: the root mean square, over every
/// joint's Coulomb and viscous friction, of the scatter of their values beyond what their own spreads explain
/// (`max(0, variance - mean std^2)`) over the value squared. `None` for fewer than two runs.
pub fn measured_share(runs: &[Identification]) -> Option<f64> {
    let k = runs.len();
    if k < 2 {
        return None;
    }
    let mut shares = Vec::new();
    for j in 0..runs[0].joints.len() {
        for pick in [|j: &JointEstimate| j.coulomb, |j: &JointEstimate| j.viscous] {
            let estimates: Vec<Estimated> = runs.iter().map(|r| pick(&r.joints[j])).collect();
            let mean = estimates.iter().map(|e| e.value).sum::<f64>() / k as f64;
            let variance = estimates.iter().map(|e| (e.value - mean).powi(2)).sum::<f64>() / (k - 1) as f64;
            let within = estimates.iter().map(|e| e.std * e.std).sum::<f64>() / k as f64;
            if mean.abs() > 0.0 {
                shares.push((variance - within).max(0.0) / (mean * mean));
            }
        }
    }
    (!shares.is_empty()).then(|| (shares.iter().sum::<f64>() / shares.len() as f64).sqrt())
}

impl Identification {
    /// Gives each joint's friction and offset its spread over runs, for logs that are `runs` runs of the arm each
    /// moving them by `share` (of the friction's value; of the Coulomb friction for the offset) independently: the
    /// arm's value over runs is known to `sqrt(std^2 + (share x scale)^2 / runs)`. Two calibrations from other runs
    /// agree within these, where the one-run spreads (`std`) hold only for the same run's conditions. A share of 0
    /// gives none.
    pub fn over_runs(&mut self, share: f64, runs: usize) {
        self.run_to_run = share;
        let runs = runs.max(1) as f64;
        for j in &mut self.joints {
            let (coulomb, viscous) = (j.coulomb.value.abs(), j.viscous.value.abs());
            for (e, scale) in [(&mut j.coulomb, coulomb), (&mut j.viscous, viscous), (&mut j.offset, coulomb)] {
                e.over_runs = (share > 0.0).then(|| e.std.hypot(share * scale / runs.sqrt()));
            }
        }
    }
}

fn cell(e: &Estimated) -> String {
    let mark = if e.decided == Decided::Prior { "*" } else { " " };
    match e.scale {
        Scale::Linear => format!("{:>11.5} ±{:<9.2e}{mark}", e.value, e.std),
        Scale::Log => format!("{:>11.5} ×÷{:<8.4}{mark}", e.value, e.std.exp()),
    }
}

impl std::fmt::Display for Identification {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.fmt_signals(f)?;
        self.fmt_links(f)?;
        self.fmt_joints(f)?;
        self.fmt_verdict(f)
    }
}

impl Identification {
    /// What was read: the logs, the velocity and effort as taken, the rank.
    fn fmt_signals(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} log(s), {} samples at {:.0} Hz, {} torque rows{}",
            self.logs.len(),
            self.samples,
            self.rate,
            self.rows,
            match self.velocity.step {
                1 => String::new(),
                k => format!(" (every {k}{} sample: at least 4 per period of the low-pass cut-off)", ordinal_suffix(k)),
            }
        )?;
        let v = &self.velocity;
        match (v.source, v.cutoff) {
            (VelocitySource::Positions, Some(fc)) => {
                writeln!(f, "velocity: from positions, low-passed at {fc:.1} Hz ({})", v.reason)?
            }
            (_, Some(fc)) => writeln!(f, "velocity: as logged, low-passed at {fc:.1} Hz ({})", v.reason)?,
            (_, None) => writeln!(f, "velocity: as logged ({})", v.reason)?,
        }
        writeln!(f, "effort: {} ({})", self.effort.name(), self.effort_reason)?;
        writeln!(f, "{} of {} parameter combinations identifiable", self.rank, self.parameters)
    }

    /// Each link's mass, centre of mass and inertia about it.
    fn fmt_links(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "\nlinks (value ± standard deviation; mass ×÷ a factor, one standard deviation of its logarithm; * = the \
             logs tell it less than the URDF does: its spread is over half the URDF's, and its value is the URDF's \
             moved only as far as what the logs do tell pulls it)"
        )?;
        writeln!(
            f,
            "  {:<22} {:>23} {:>23} {:>23} {:>23}",
            "link", "mass [kg]", "com x [m]", "com y [m]", "com z [m]"
        )?;
        for l in &self.links {
            writeln!(
                f,
                "  {:<22} {} {} {} {}",
                l.name,
                cell(&l.mass),
                cell(&l.com[0]),
                cell(&l.com[1]),
                cell(&l.com[2])
            )?;
        }
        writeln!(f, "  {:<22} {:>23} {:>23} {:>23}   inertia about the COM [kg m^2]", "", "ixx", "iyy", "izz")?;
        for l in &self.links {
            let i = &l.inertia;
            writeln!(f, "  {:<22} {} {} {}", l.name, cell(&i[0]), cell(&i[3]), cell(&i[5]))?;
        }
        writeln!(f, "  {:<22} {:>23} {:>23} {:>23}", "", "ixy", "ixz", "iyz")?;
        for l in &self.links {
            let i = &l.inertia;
            writeln!(f, "  {:<22} {} {} {}", l.name, cell(&i[1]), cell(&i[2]), cell(&i[4]))?;
        }
        Ok(())
    }

    /// Each joint's friction, drive terms, noise and fit, and their spreads over runs.
    fn fmt_joints(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "\njoints (friction in N m and N m s/rad, rotor inertia in kg m^2, offset in N m; prismatic: N, N s/m, kg, N)"
        )?;
        writeln!(
            f,
            "  {:<22} {:>23} {:>23} {:>23} {:>23} {:>10} {:>8}",
            "joint", "coulomb", "viscous", "rotor inertia", "offset", "noise", "NRMSE"
        )?;
        for j in &self.joints {
            let (c, v, a, o) = (cell(&j.coulomb), cell(&j.viscous), cell(&j.armature), cell(&j.offset));
            writeln!(f, "  {:<22} {c} {v} {a} {o} {:>10.2e} {:>8.4}", j.name, j.noise, j.nrmse)?;
        }
        if self.joints.iter().any(|j| j.coulomb.over_runs.is_some()) {
            writeln!(
                f,
                "  over runs (each log a run; friction moves by --run-to-run of its value from run to run): what a \
                 calibration from other runs agrees within"
            )?;
            let runs = |e: &Estimated| format!("{:>23}", e.over_runs.map_or(String::new(), |s| format!("±{s:<9.2e} ")));
            for j in &self.joints {
                let (c, v, o) = (runs(&j.coulomb), runs(&j.viscous), runs(&j.offset));
                writeln!(f, "  {:<22} {c} {v} {:>23} {o}", j.name, "")?;
            }
        }
        Ok(())
    }

    /// How well the calibration predicts the logs, and what the user should know.
    fn fmt_verdict(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "\ntorque NRMSE on the logs: calibrated {:.4}, URDF as given {:.4}, least squares (base parameters) {:.4}",
            self.nrmse_calibrated, self.nrmse_urdf, self.nrmse_least_squares
        )?;
        if self.nrmse_calibrated > self.nrmse_urdf {
            writeln!(
                f,
                "warning: the calibrated robot predicts these logs' torques worse than the URDF as given; keep the URDF, \
                 or record richer motion"
            )?;
        }
        if !self.converged {
            writeln!(f, "warning: the search stopped after {} iterations without converging", self.iterations)?;
        }
        for w in &self.warnings {
            writeln!(f, "warning: {w}")?;
        }
        for n in &self.notes {
            writeln!(f, "note: {n}")?;
        }
        Ok(())
    }
}

/// The English ordinal's ending of `k` (2nd, 3rd, 11th, 12th, 21st).
fn ordinal_suffix(k: usize) -> &'static str {
    match (k % 10, k % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mass believed to within a factor: its spread is of the logarithm, so a truth a factor `e^s` away is one
    /// standard deviation away on either side (a linear spread would put the two sides at different distances).
    #[test]
    fn a_masss_spread_is_a_factor_and_its_z_is_symmetric_in_the_log() {
        let e = Estimated::positive(2.0, 0.6, 2.5, 1.0);
        assert_eq!(e.scale, Scale::Log);
        assert!((e.std - 0.3).abs() < 1e-15 && (e.prior_std - 0.4).abs() < 1e-15);
        for truth in [2.0 * 0.3f64.exp(), 2.0 / 0.3f64.exp()] {
            assert!((e.z(truth).abs() - 1.0).abs() < 1e-12, "{truth}: z {}", e.z(truth));
        }
        // What decided it is judged on one scale for both: 0.6 < 0.5 * 1.0 is false, so the prior.
        assert_eq!(e.decided, Decided::Prior);
        let linear = Estimated::new(2.0, 0.6, 2.5, 1.0);
        assert!((linear.z(2.6) - -1.0).abs() < 1e-12);
    }

    /// Each reported spread is the larger of the two covariances', parameter by parameter: a covariance wide only in
    /// the COM's coordinates widens only the COM, one wide only in the mass's widens only the mass.
    #[test]
    fn a_link_s_spreads_are_the_larger_of_the_sandwich_s_and_laplace_s_each() {
        let theta = [0.3, -1.0, -1.2, -1.4, 0.01, -0.02, 0.005, 0.05, -0.02, 0.1];
        let base = DMatrix::from_diagonal_element(COORDINATES, COORDINATES, 1e-6);
        let mut com = base.clone();
        for k in standard::T {
            com[(k, k)] = 1e-2;
        }
        let mut mass = base.clone();
        mass[(standard::ALPHA, standard::ALPHA)] = 1e-2;
        let (b, c, m) = (reported_std(&theta, &base), reported_std(&theta, &com), reported_std(&theta, &mass));
        let got = link_std(&theta, &com, &mass);
        for k in 0..10 {
            assert_eq!(got[k], c[k].max(m[k]), "parameter {k}");
        }
        // The COM's three from the first, the mass from the second; neither is the narrow one's.
        for k in 1..4 {
            assert!(got[k] > 10.0 * b[k] && got[k] == c[k], "COM {k}: {} vs {}", got[k], b[k]);
        }
        assert!(got[0] > 10.0 * b[0] && got[0] == m[0], "mass: {} vs {}", got[0], b[0]);
    }
}
