//! The physics estimator's cache: the evidence of every window and every whole recording of a dataset
//! (`crate::evidence`), with its labels and robot.

use std::io::{self, Read, Write};
use std::path::Path;

use dynforge_identify::{Evidence, PAIRING_REVISION, ParameterPrior, packed_len};
use dynforge_proto::NUM_LABELS;
use dynforge_proto::lock::RunLock;
use dynforge_recording::{Recording, read_shard_bytes};

use super::codec::{Decoder, Encoder};
use super::partitions::PartitionsError;
use super::{CacheError, CacheKey, Cached, Loaded, Skipped, Stored};
use crate::evidence::{NOISE_FLOOR, recording_evidence};
use crate::split::{HoldOut, Origin, Split, SplitRule, back_to_back, origins};
use crate::window::WindowSpec;

/// Pieces of evidence with their robot and labels, stored flat.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EvidenceList {
    pub rank: usize,
    pub robots: Vec<u64>,
    /// The robot's trajectory index of the recording each piece is (or is cut from).
    pub trajectories: Vec<u32>,
    pub labels: Vec<[f64; NUM_LABELS]>,
    /// For windows: the index of their recording in the set's recordings.
    pub recording: Vec<u64>,
    h: Vec<f64>,
    b: Vec<f64>,
}

impl EvidenceList {
    fn new(rank: usize) -> Self {
        EvidenceList { rank, ..Default::default() }
    }

    pub fn len(&self) -> usize {
        self.robots.len()
    }

    pub fn is_empty(&self) -> bool {
        self.robots.is_empty()
    }

    fn push(&mut self, (robot, trajectory): (u64, u32), labels: [f64; NUM_LABELS], recording: u64, e: &Evidence) {
        self.robots.push(robot);
        self.trajectories.push(trajectory);
        self.labels.push(labels);
        self.recording.push(recording);
        self.h.extend(&e.h);
        self.b.extend(&e.b);
    }

    /// Appends item `i` of `other`, as part of recording `recording`.
    fn push_from(&mut self, other: &EvidenceList, i: usize, recording: u64) {
        let (r, p) = (self.rank, packed_len(self.rank));
        self.robots.push(other.robots[i]);
        self.trajectories.push(other.trajectories[i]);
        self.labels.push(other.labels[i]);
        self.recording.push(recording);
        self.h.extend(&other.h[i * p..(i + 1) * p]);
        self.b.extend(&other.b[i * r..(i + 1) * r]);
    }

    /// Evidence `i`.
    pub fn get(&self, i: usize) -> Evidence {
        let (r, p) = (self.rank, packed_len(self.rank));
        Evidence { rank: r, h: self.h[i * p..(i + 1) * p].to_vec(), b: self.b[i * r..(i + 1) * r].to_vec() }
    }

    /// The packed excitation `H` of evidence `i` alone.
    pub fn excitation(&self, i: usize) -> &[f64] {
        let p = packed_len(self.rank);
        &self.h[i * p..(i + 1) * p]
    }

    /// Where each piece comes from, for a list of windows of `spec` (stored recording by recording, each
    /// recording's as [`WindowSpec::windows`] lists them).
    pub fn origins(&self, spec: &WindowSpec) -> Vec<Origin> {
        origins(&self.robots, &self.trajectories, spec)
    }

    /// Which pieces of a list of windows of `spec` (stored as for [`Self::origins`]) are back to back
    /// ([`WindowSpec::back_to_back`]).
    pub fn back_to_back(&self, spec: &WindowSpec) -> Vec<bool> {
        back_to_back(&self.robots, &self.trajectories, spec)
    }

    /// Evidence summed per robot over the pieces `keep` accepts (by index): (robot, labels, evidence).
    pub fn per_robot(&self, keep: impl Fn(usize) -> bool) -> Vec<(u64, [f64; NUM_LABELS], Evidence)> {
        let mut out: std::collections::BTreeMap<u64, ([f64; NUM_LABELS], Evidence)> = Default::default();
        for i in (0..self.len()).filter(|&i| keep(i)) {
            let e = self.get(i);
            match out.get_mut(&self.robots[i]) {
                Some((_, sum)) => sum.add(&e),
                None => {
                    out.insert(self.robots[i], (self.labels[i], e));
                }
            }
        }
        out.into_iter().map(|(r, (y, e))| (r, y, e)).collect()
    }

    fn encode<W: Write>(&self, e: &mut Encoder<W>) {
        e.u64s([self.len() as u64]).u64s(self.robots.iter().copied()).u64s(self.recording.iter().copied());
        e.u64s(self.trajectories.iter().map(|&t| t as u64));
        self.labels.iter().for_each(|l| _ = e.f64s(l));
        e.f64s(&self.h).f64s(&self.b);
    }

    fn decode<R: Read>(d: &mut Decoder<R>, rank: usize) -> Option<Self> {
        let n = d.usize()?;
        let robots = d.u64s(n)?;
        let recording = d.u64s(n)?;
        let trajectories = d.u64s(n)?.into_iter().map(u32::try_from).collect::<Result<_, _>>().ok()?;
        let labels = d.label_rows(n)?;
        let h = d.f64s(n.checked_mul(packed_len(rank))?)?;
        let b = d.f64s(n.checked_mul(rank)?)?;
        Some(EvidenceList { rank, robots, trajectories, labels, recording, h, b })
    }
}

/// A dataset's physics: the evidence of every window (same windows, same order as the window cache's) and of every
/// whole recording.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicsSet {
    pub spec: WindowSpec,
    pub windows: EvidenceList,
    pub recordings: EvidenceList,
    /// Whether this came from the cache file.
    pub hit: bool,
}

/// What determines a physics cache besides the dataset.
#[derive(Debug, Clone)]
pub struct EvidenceSettings {
    pub spec: WindowSpec,
    pub prior: ParameterPrior,
}

/// One recording's contribution: its robot, labels, windows' and whole evidence.
pub struct RecordingEvidence {
    robot: u64,
    trajectory: u32,
    labels: [f64; NUM_LABELS],
    windows: Vec<Evidence>,
    whole: Evidence,
}

const MAGIC: &[u8; 8] = b"DFPHY002";

impl PhysicsSet {
    /// An empty set for evidence in the coordinates of a prior of rank `rank`.
    pub fn new(spec: WindowSpec, rank: usize) -> Self {
        PhysicsSet { spec, windows: EvidenceList::new(rank), recordings: EvidenceList::new(rank), hit: false }
    }

    /// The physics of every shard of the `generate` directory `dir` (see [`super::load_or_build`]), with the shards
    /// that had to be skipped.
    pub fn load_or_build(
        dir: &Path,
        spec: &WindowSpec,
        prior: &ParameterPrior,
        progress: impl FnMut(usize, usize) -> bool,
    ) -> Result<(Self, Vec<Skipped>), CacheError> {
        Self::load(dir, spec, prior, None, progress).map(|l| (l.cache, l.skipped))
    }

    /// [`Self::load_or_build`] with all it found out, by the holder of `dir`'s lock `lock` if given.
    pub fn load(
        dir: &Path,
        spec: &WindowSpec,
        prior: &ParameterPrior,
        lock: Option<&RunLock>,
        progress: impl FnMut(usize, usize) -> bool,
    ) -> Result<Loaded<Self>, CacheError> {
        super::load_or_build(dir, &EvidenceSettings { spec: *spec, prior: prior.clone() }, lock, progress)
    }

    /// The side of every window and of every recording under `rule`. A recording is training data only when all its
    /// windows are (under a split by window a recording's evidence holds its windows'); otherwise the side of its
    /// robot or trajectory.
    pub fn sides(&self, rule: &SplitRule) -> (Vec<Split>, Vec<Split>) {
        let windows: Vec<Split> = self.windows.origins(&self.spec).into_iter().map(|o| rule.side(o)).collect();
        let r = &self.recordings;
        let recordings = match rule.by {
            HoldOut::Windows => {
                let mut sides = vec![Split::Train; r.len()];
                for (side, &k) in windows.iter().zip(&self.windows.recording) {
                    if *side == Split::Validation {
                        sides[k as usize] = Split::Validation;
                    }
                }
                sides
            }
            _ => (0..r.len())
                .map(|i| rule.side(Origin { robot: r.robots[i], trajectory: r.trajectories[i], segment: 0 }))
                .collect(),
        };
        (windows, recordings)
    }

    /// Adds a dataset recording (with labels and robot id): its windows' and its whole evidence.
    pub fn add(&mut self, rec: &Recording, prior: &ParameterPrior) -> Result<(), Skipped> {
        let settings = EvidenceSettings { spec: self.spec, prior: prior.clone() };
        let evidence = of_recording(rec, &settings)?;
        self.append(&rec.path, evidence)
    }
}

fn of_recording(rec: &Recording, s: &EvidenceSettings) -> Result<RecordingEvidence, Skipped> {
    let (Some(labels), Some(robot), Some(trajectory)) = (rec.labels, rec.robot, rec.trajectory_index) else {
        return Err(Skipped::new(&rec.path, "no labels, robot or trajectory index (not a dataset shard)"));
    };
    let (windows, whole) = recording_evidence(rec, &s.prior, &s.spec)?;
    Ok(RecordingEvidence { robot, trajectory, labels, windows, whole })
}

impl Cached for PhysicsSet {
    const KIND: &'static str = "physics";
    const CHUNK_PER_THREAD: usize = 8;
    type Settings = EvidenceSettings;
    type Shard = RecordingEvidence;
    type Added = ();

    /// The window geometry, the noise model and the prior.
    fn key(s: &EvidenceSettings) -> CacheKey {
        let (spec, prior) = (&s.spec, &s.prior);
        let mut m = format!("physics|{spec}|{}|{}|{}|", NOISE_FLOOR, prior.rank(), PAIRING_REVISION).into_bytes();
        for v in prior.mean().iter().chain(prior.factor()) {
            m.extend(v.to_le_bytes());
        }
        m.extend(MAGIC);
        CacheKey::new(Self::KIND, &m)
    }

    fn empty(s: &EvidenceSettings) -> Self {
        PhysicsSet::new(s.spec, s.prior.rank())
    }

    fn restore(&mut self, s: &EvidenceSettings) {
        self.spec = s.spec;
    }

    fn read_shard(path: &Path, bytes: &[u8], s: &EvidenceSettings) -> Result<RecordingEvidence, Skipped> {
        of_recording(&read_shard_bytes(bytes, path, None)?, s)
    }

    fn append(&mut self, _path: &Path, r: RecordingEvidence) -> Result<(), Skipped> {
        let k = self.recordings.len() as u64;
        self.recordings.push((r.robot, r.trajectory), r.labels, k, &r.whole);
        for w in &r.windows {
            self.windows.push((r.robot, r.trajectory), r.labels, k, w);
        }
        Ok(())
    }

    fn encode<W: Write>(&self, out: W) -> io::Result<W> {
        let mut e = Encoder::new(out, MAGIC);
        e.u64s([self.spec.len, self.spec.stride, self.spec.ssr, self.windows.rank].map(|v| v as u64));
        self.windows.encode(&mut e);
        self.recordings.encode(&mut e);
        e.finish()
    }

    fn decode<R: Read>(input: R, len: u64) -> Option<Self> {
        let mut d = Decoder::open(input, len, MAGIC)?;
        let spec = WindowSpec::new(d.usize()?, d.usize()?, d.usize()?);
        let rank = d.usize()?;
        let windows = EvidenceList::decode(&mut d, rank)?;
        let recordings = EvidenceList::decode(&mut d, rank)?;
        d.finish()?;
        Some(PhysicsSet { spec, windows, recordings, hit: true })
    }

    /// In memory: every part decoded, then combined.
    fn combine_into<W: Write>(parts: &[Stored], out: W) -> Result<W, PartitionsError> {
        let sets = parts.iter().map(Stored::decode::<PhysicsSet>).collect::<Result<Vec<_>, _>>()?;
        PhysicsSet::combine(&sets).encode(out).map_err(PartitionsError::Write)
    }
}

impl PhysicsSet {
    /// Recordings and windows in merged order, each window still pointing at its recording.
    fn combine(parts: &[PhysicsSet]) -> PhysicsSet {
        let (spec, rank) = parts.first().map_or((WindowSpec::default(), 0), |p| (p.spec, p.windows.rank));
        let mut out = PhysicsSet::new(spec, rank);
        let mut moved: Vec<Vec<u64>> = parts.iter().map(|p| vec![0; p.recordings.len()]).collect();
        let robots = |f: fn(&PhysicsSet) -> &EvidenceList| parts.iter().map(|p| &f(p).robots[..]).collect::<Vec<_>>();
        for (p, items) in super::merged_order(&robots(|s| &s.recordings)) {
            for i in items {
                moved[p][i] = out.recordings.len() as u64;
                out.recordings.push_from(&parts[p].recordings, i, moved[p][i]);
            }
        }
        for (p, items) in super::merged_order(&robots(|s| &s.windows)) {
            for i in items {
                let list = &parts[p].windows;
                out.windows.push_from(list, i, moved[p][list.recording[i] as usize]);
            }
        }
        out
    }
}
