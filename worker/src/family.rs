//! The jobs of a robot's family (`generate --urdf`): robot `r` is a variant of the run's URDF, its inertial
//! parameters and friction drawn around the URDF's with the robot's prior (`dynforge_robot::prior`) (every draw a physical body), and
//! trajectory `t` is excitation `t` followed by the same controller and failure checks as the generator's robots.
//! Shards carry the variant's URDF and its standard parameters as labels ([`standard_names`]).
//!
//! Self-collision is not checked here: the excitation was designed clear of it with the URDF's collision geometry
//! (`dynforge excite`), the variants share the kinematics, and the controller follows the reference to within
//! millimetres; a run that strays is caught by the timeout and limit checks.

use std::collections::BTreeMap;
use std::path::Path;

use dynforge_proto::family::{Family, FamilyError, Sources};
use dynforge_proto::fourier::{Excitation, Fourier};
use dynforge_proto::job::Job;
use dynforge_proto::shard::{JobRecord, META_JOB, META_LABELS, META_TRAJECTORY, RobotSource};
use dynforge_proto::sim::EngineKind;
use dynforge_proto::spread::Spread;
use dynforge_robot::parameters::{standard_names, standard_parameters};
use dynforge_robot::prior::{CoordinatePrior, PriorError, friction_coordinate};
use dynforge_robot::rng::{Rng, domain};
use dynforge_robot::spatial::Se3;
use dynforge_robot::urdf::{Unsplit, Welds, parse_welded, patch_welded};
use dynforge_robot::{Model, ModelError};
use dynforge_shard::Metadata;
use nalgebra::Vector3;

use crate::collision::{Collides, Contact};
use crate::output::{JobError, Outcome, write_shard};
use crate::simulate::{Arm, Discard, Simulation, simulate, unsupported};
use crate::trajectory::Reference;
use dynforge_proto::sim::SimConfig;

/// Why a family cannot be simulated at all (as opposed to one variant's discard).
#[derive(Debug, thiserror::Error)]
pub enum FamilySetupError {
    #[error(transparent)]
    Files(#[from] FamilyError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("the URDF's inertials are not physical bodies: {0}")]
    Prior(#[from] PriorError),
    #[error("{file}: joint '{joint}' is {why}, which the {engine} engine does not simulate (--engine native does)")]
    Engine { file: String, joint: String, why: &'static str, engine: &'static str },
    #[error("{file} moves joints {found:?}, the URDF (with its welds) has {expected:?}")]
    Joints { file: String, found: Vec<String>, expected: Vec<String> },
    #[error(
        "{file}: joint '{joint}' {reaches}, beyond the limit of the URDF {urdf} ({limit}): every variant would be \
         discarded. The excitation was designed for other limits: design it for this URDF (`dynforge excite --urdf`)"
    )]
    Limits { file: String, joint: String, reaches: String, urdf: String, limit: String },
}

/// Excitation `t` then a hold at its start pose (where it ends).
struct Excited<'a> {
    series: &'a Fourier,
    hold: f64,
}

impl Reference for Excited<'_> {
    fn start(&self) -> &[f64] {
        &self.series.start
    }

    fn goal(&self) -> &[f64] {
        &self.series.start
    }

    fn total(&self) -> f64 {
        self.series.period + self.hold
    }

    fn at(&self, t: f64) -> [Vec<f64>; 3] {
        let n = self.series.joints();
        let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        // Periodic, at rest at both ends: past the period the series holds its start.
        self.series.at(t.min(self.series.period), &mut q, &mut qd, &mut qdd);
        [q, qd, qdd]
    }
}

/// Share of a joint's range (or speed limit) an excitation may pass it by: `excite` keeps a margin inside both, so
/// more is an excitation designed for other limits.
const LIMIT_SLACK: f64 = 0.01;

/// The first joint of `model` that `series` takes beyond its position range or speed limit (by more than
/// [`LIMIT_SLACK`]), sampled 64 times per period of its highest harmonic: its name, what it reaches and the limit.
fn beyond_limits(model: &Model, series: &Fourier) -> Option<(String, String, String)> {
    let n = series.joints();
    let harmonics = series.a.iter().map(Vec::len).max().unwrap_or(1);
    let samples = (64 * harmonics).max(2000);
    let (mut lo, mut hi, mut fast) = (series.start.clone(), series.start.clone(), vec![0.0f64; n]);
    let (mut q, mut qd, mut qdd) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for i in 0..=samples {
        series.at(series.period * i as f64 / samples as f64, &mut q, &mut qd, &mut qdd);
        for j in 0..n {
            (lo[j], hi[j], fast[j]) = (lo[j].min(q[j]), hi[j].max(q[j]), fast[j].max(qd[j].abs()));
        }
    }
    model.joints().iter().enumerate().find_map(|(j, joint)| {
        let l = &joint.limits;
        if let Some((lower, upper)) = l.range() {
            let slack = LIMIT_SLACK * (upper - lower);
            if lo[j] < lower - slack || hi[j] > upper + slack {
                let reaches = format!("moves over [{:.4}, {:.4}]", lo[j], hi[j]);
                return Some((joint.name.clone(), reaches, format!("range [{lower}, {upper}]")));
            }
        }
        (fast[j] > (1.0 + LIMIT_SLACK) * l.velocity)
            .then(|| (joint.name.clone(), format!("reaches speed {:.4}", fast[j]), format!("speed {}", l.velocity)))
    })
}

/// Position error [rad or m] at which a family's joint loop pushes through twice its expected Coulomb friction
/// (measured on the Panda's family: 0.02 discards 103 of 256 runs, 0.005 24, 0.002 15, 0.001 18).
pub const TRACKING: f64 = 0.002;

/// See the module documentation: no self-collision check for a family.
struct Unchecked;

impl Collides for Unchecked {
    fn contact(&self, _: &[Se3]) -> Option<Contact> {
        None
    }
}

/// The family of `urdf` on the excitations in `excitations` (as `dynforge excite --out` wrote them), checked as the
/// workers will read it: its manifest record and its files; refused up front if `engine` cannot simulate the URDF
/// (with its welds).
pub fn prepare(
    urdf: &Path,
    excitations: &Path,
    welds: Welds,
    spread: Spread,
    engine: EngineKind,
) -> Result<(Family, Sources), FamilySetupError> {
    let sources = Sources::read(urdf, excitations)?;
    // The engine first: a family it cannot simulate is refused whatever else is wrong with it.
    let model = parse_welded(&sources.urdf, &urdf.display().to_string(), &welds)?;
    if let Some(Discard::Unsupported { engine, joint, why }) = unsupported(engine, &model) {
        let joint = model.joints()[joint].name.clone();
        return Err(FamilySetupError::Engine { file: urdf.display().to_string(), joint, why, engine });
    }
    let family = sources.family(welds, spread);
    FamilyRunner::of(&sources, &family, urdf, excitations)?;
    Ok((family, sources))
}

/// A run's family, read once per worker.
pub struct FamilyRunner {
    urdf: String,
    welds: Welds,
    nominal: Model,
    prior: CoordinatePrior,
    excitations: Vec<Excitation>,
    family: Family,
}

impl FamilyRunner {
    /// The family of the run in `run_dir`, from its copies of the URDF and the excitations.
    pub fn new(run_dir: &Path, family: &Family) -> Result<Self, FamilySetupError> {
        let dir = run_dir.join(dynforge_proto::family::DIR);
        Self::of(&Sources::of_run(run_dir, family)?, family, &dir.join(dynforge_proto::family::URDF), &dir)
    }

    /// The family of `sources` (read from the URDF `urdf` and the excitations in `dir`, which messages name).
    fn of(sources: &Sources, family: &Family, urdf: &Path, dir: &Path) -> Result<Self, FamilySetupError> {
        let welds: Welds = family.welds.clone();
        let nominal = parse_welded(&sources.urdf, &urdf.display().to_string(), &welds)?;
        let excitations = sources.parsed()?;
        let expected: Vec<String> = nominal.joints().iter().map(|j| j.name.clone()).collect();
        for (k, e) in excitations.iter().enumerate() {
            if e.joints != expected {
                let file = dir.join(dynforge_proto::family::excitation_file(k)).display().to_string();
                return Err(FamilySetupError::Joints { file, found: e.joints.clone(), expected });
            }
        }
        for (k, e) in excitations.iter().enumerate() {
            if let Some((joint, reaches, limit)) = beyond_limits(&nominal, &e.series) {
                let file = dir.join(dynforge_proto::family::excitation_file(k)).display().to_string();
                let urdf = urdf.display().to_string();
                return Err(FamilySetupError::Limits { file, joint, reaches, urdf, limit });
            }
        }
        let prior = CoordinatePrior::of(&nominal, family.spread)?;
        Ok(FamilyRunner { urdf: sources.urdf.clone(), welds, nominal, prior, excitations, family: family.clone() })
    }

    /// Excitations, one per trajectory of a robot.
    pub fn trajectories(&self) -> usize {
        self.excitations.len()
    }

    /// Variant `robot` of the dataset of `seed`.
    pub fn variant(&self, seed: u64, robot: u64) -> Result<Model, PriorError> {
        let mut rng = Rng::stream(seed, &[domain::FAMILY, robot]);
        self.prior.draw_variant(&self.nominal, || rng.normal())
    }

    /// The run's gains for this family: a joint's stiffness floor holds it within [`TRACKING`] of the reference
    /// against twice the Coulomb friction the prior expects (the generator's floors are for its own robots, and a
    /// 7-joint arm's light wrists would stick and slip behind the excitation without this).
    fn gains(&self, sim: &SimConfig) -> SimConfig {
        let n = self.nominal.dof();
        let mut sim = sim.clone();
        let spread = self.prior.marginal_std();
        sim.gains.inertia_floor = (0..n)
            .map(|j| {
                let (omega, floor) = sim.gains.joint(j);
                let coulomb = spread[friction_coordinate(n, j, 0)];
                floor.max(2.0 * coulomb / TRACKING / (omega * omega))
            })
            .collect();
        sim.gains.per_joint_scale = true;
        sim
    }

    /// Simulates a job without writing anything: the variant, and its recording or why it was discarded.
    pub fn simulate(&self, job: &Job, sim: &SimConfig) -> Result<(Model, Result<Simulation, Discard>), JobError> {
        let sim = &self.gains(sim);
        let model = self.variant(job.seed, job.robot).map_err(|e| JobError::Family(e.to_string()))?;
        let series = &self.excitations[job.trajectory as usize % self.excitations.len()].series;
        let last = model.dof() - 1;
        let arm = Arm {
            model: &model,
            tip: (last, Vector3::zeros()),
            collision: &Unchecked,
            feedforward: Some(&self.nominal),
        };
        let result = simulate(&arm, &Excited { series, hold: sim.trajectory.hold }, sim);
        Ok((model, result))
    }

    /// Runs a job and writes its shard into `out_dir`.
    pub fn run(&self, job: &Job, sim: &SimConfig, out_dir: &Path) -> Result<Outcome, JobError> {
        let (model, result) = self.simulate(job, sim)?;
        let rec = match result {
            Ok(rec) => rec,
            Err(d) => return Ok(Outcome::Discarded(d)),
        };
        let (urdf, _) = patch_welded(&self.urdf, dynforge_proto::family::URDF, &model, &self.welds, Unsplit::Exact)?;
        let metadata = self.metadata(job, sim, &model);
        write_shard(&out_dir.join(job.shard_name(sim.engine.name())), &model, &urdf, &rec, &metadata)
    }

    fn metadata(&self, job: &Job, sim: &SimConfig, model: &Model) -> Metadata {
        let source = RobotSource::Family { urdf_hash: self.family.urdf_hash.clone() };
        let job_meta = JobRecord { job: *job, engine: sim.engine.name().to_string(), dt: sim.dt, source }.to_metadata();
        let labels =
            standard_names(model).into_iter().zip(standard_parameters(model)).map(|(k, v)| (k, format!("{v}")));
        let k = job.trajectory as usize % self.excitations.len();
        let traj_meta = BTreeMap::from([
            ("excitation".to_string(), self.family.excitation_hashes[k].clone()),
            ("move_end".to_string(), format!("{}", self.excitations[k].series.period)),
        ]);
        BTreeMap::from([
            (META_JOB.to_string(), job_meta),
            (META_LABELS.to_string(), labels.collect()),
            (META_TRAJECTORY.to_string(), traj_meta),
        ])
    }
}
