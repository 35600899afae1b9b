//! The shard contract: what a dataset shard (an MCAP file) holds, in the same form `ros2 bag record` writes, so one
//! reader serves our shards and a real robot's bags.
//!
//! - `/joint_states`: `sensor_msgs/msg/JointState`, CDR, one message per sample (1 kHz), stamped with sim time; the
//!   effort is the motor torque applied over the following period.
//! - `/robot_description`: `std_msgs/msg/String` holding the robot's URDF (as Foxglove expects), one message at t=0.
//! - Metadata records: [`META_JOB`] (job identity), [`META_LABELS`] (the 38 labels by name; a family's shard: its
//!   standard parameters, `LINK.mass` .. `JOINT.viscous`), [`META_TRAJECTORY`] (start/goal and the move/hold
//!   boundaries).
//!
//! The CDR codec below is plain little-endian XCDR1: a 4-byte encapsulation header `00 01 00 00`, then every
//! primitive aligned to its own size counted from the end of that header; strings are a `u32` length including a
//! trailing NUL, the bytes, and the NUL; sequences are a `u32` count then the elements.

use std::collections::BTreeMap;

use crate::job::Job;

pub const TOPIC_JOINT_STATES: &str = "/joint_states";
pub const TOPIC_ROBOT_DESCRIPTION: &str = "/robot_description";
pub const SCHEMA_JOINT_STATE: &str = "sensor_msgs/msg/JointState";
pub const SCHEMA_STRING: &str = "std_msgs/msg/String";
pub const SCHEMA_JOINT_TRAJECTORY: &str = "trajectory_msgs/msg/JointTrajectory";
/// Where a joint_trajectory_controller named `joint_trajectory_controller` takes its trajectories.
pub const TOPIC_JOINT_TRAJECTORY: &str = "/joint_trajectory_controller/joint_trajectory";
pub const SCHEMA_ENCODING: &str = "ros2msg";
pub const MESSAGE_ENCODING: &str = "cdr";
/// MCAP profile, as rosbag2 writes it.
pub const PROFILE: &str = "ros2";
/// The writer's library string (fixed, so shards stay byte-identical across dependency upgrades).
pub const LIBRARY: &str = "dynforge-shard/1";

/// The file name of the shard of (robot, trajectory) simulated by `engine`: derived from the job alone, so
/// re-running a job rewrites the same file, and a reader can tell a shard's robot without opening it.
pub fn file_name(robot: u64, trajectory: u32, engine: &str) -> String {
    format!("{}{trajectory:02}-{engine}.mcap", robot_prefix(robot))
}

/// The start every shard name of `robot` shares: robots sort by it as their shards sort by name (which is not
/// numeric order past 999,999).
pub fn robot_prefix(robot: u64) -> String {
    format!("r{robot:06}-t")
}

/// The robot of a shard named by [`file_name`]; `None` for any other name.
pub fn robot_of_file_name(name: &str) -> Option<u64> {
    let rest = name.strip_prefix('r')?.strip_suffix(".mcap")?;
    let (robot, rest) = rest.split_once("-t")?;
    let (trajectory, engine) = rest.split_once('-')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    (digits(robot) && digits(trajectory) && !engine.is_empty()).then(|| robot.parse().ok())?
}

/// Full `ros2msg` definition of `sensor_msgs/msg/JointState` with its dependencies, as rosbag2 stores it.
pub const JOINT_STATE_DEFINITION: &str = include_str!("schemas/sensor_msgs_JointState.ros2msg");
/// `ros2msg` definition of `trajectory_msgs/msg/JointTrajectory`.
pub const JOINT_TRAJECTORY_DEFINITION: &str = include_str!("schemas/trajectory_msgs_JointTrajectory.ros2msg");
/// `ros2msg` definition of `std_msgs/msg/String`.
pub const STRING_DEFINITION: &str = include_str!("schemas/std_msgs_String.ros2msg");

/// Metadata record holding the job identity: `seed`, `robot`, `trajectory`, `engine`, `dt`, `generator_version`,
/// `dynforge_version`.
pub const META_JOB: &str = "dynforge.job";
/// Metadata record holding the 38 labels, keyed by [`crate::LABELS`] names, values in Rust's round-trip `{}` format.
pub const META_LABELS: &str = "dynforge.labels";
/// Metadata record holding the trajectory: `start`, `goal` (space-separated radians), `move_end`, `hold_end` [s].
pub const META_TRAJECTORY: &str = "dynforge.trajectory";
/// Version of this shard layout.
pub const SHARD_VERSION: u32 = 1;

/// Where a shard's robot comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RobotSource {
    /// The generator, at its version.
    Generator { version: String },
    /// A family of a user's URDF, by the URDF's hash.
    Family { urdf_hash: String },
}

/// A shard's job record ([`META_JOB`]): the job, the simulation, where its robot comes from, and the versions of the
/// shard layout and of dynforge. One definition for the worker that writes it and everyone who reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct JobRecord {
    pub job: Job,
    pub engine: String,
    /// The simulation's step [s].
    pub dt: f64,
    pub source: RobotSource,
}

/// The record's key of a family's URDF hash: present exactly in a family's shards.
const FAMILY: &str = "family";

impl JobRecord {
    /// The metadata record (values in Rust's round-trip `{}` format).
    pub fn to_metadata(&self) -> BTreeMap<String, String> {
        let source = match &self.source {
            RobotSource::Generator { version } => ("generator_version", version.clone()),
            RobotSource::Family { urdf_hash } => (FAMILY, urdf_hash.clone()),
        };
        BTreeMap::from([
            ("seed".to_string(), self.job.seed.to_string()),
            ("robot".to_string(), self.job.robot.to_string()),
            ("trajectory".to_string(), self.job.trajectory.to_string()),
            ("engine".to_string(), self.engine.clone()),
            ("dt".to_string(), format!("{}", self.dt)),
            (source.0.to_string(), source.1),
            ("shard_version".to_string(), SHARD_VERSION.to_string()),
            ("dynforge_version".to_string(), env!("CARGO_PKG_VERSION").to_string()),
        ])
    }

    /// The job a record names, if its seed, robot and trajectory are there and are numbers.
    pub fn job_of(record: &BTreeMap<String, String>) -> Option<Job> {
        let field = |key: &str| record.get(key).and_then(|v| v.parse::<u64>().ok());
        let trajectory = u32::try_from(field("trajectory")?).ok()?;
        Some(Job { seed: field("seed")?, robot: field("robot")?, trajectory })
    }

    /// Whether a record is a family's shard's (`generate --urdf`).
    pub fn is_family(record: &BTreeMap<String, String>) -> bool {
        record.contains_key(FAMILY)
    }
}

/// One `sensor_msgs/msg/JointState` message.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct JointState {
    pub sec: i32,
    pub nanosec: u32,
    pub frame_id: String,
    /// Shared between the messages of a log that name the same joints (see [`JointStateDecoder`]).
    pub name: std::sync::Arc<[String]>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

impl JointState {
    /// Stamp in nanoseconds.
    pub fn stamp_ns(&self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

/// A malformed CDR message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("malformed CDR message: {0}")]
pub struct CdrError(pub String);

const ENCAPSULATION_LE: [u8; 4] = [0, 1, 0, 0];

struct Writer(Vec<u8>);

impl Writer {
    fn new(capacity: usize) -> Self {
        let mut v = Vec::with_capacity(capacity);
        v.extend_from_slice(&ENCAPSULATION_LE);
        Writer(v)
    }
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        if !v.is_empty() {
            self.align(8);
        }
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8]) -> Result<Self, CdrError> {
        match buf.get(..4) {
            Some(h) if h[0] == 0 && h[1] == 1 => Ok(Reader { buf, pos: 4 }),
            Some(h) => Err(CdrError(format!("unsupported encapsulation {h:02x?} (only little-endian CDR)"))),
            None => Err(CdrError("shorter than the encapsulation header".into())),
        }
    }
    fn align(&mut self, n: usize) {
        self.pos += (n - (self.pos - 4) % n) % n;
    }
    fn take(&mut self, n: usize) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.buf.len());
        let end = end.ok_or_else(|| CdrError(format!("truncated at byte {} (needs {n} more)", self.pos)))?;
        let out = &self.buf[self.pos..end];
        self.pos = end;
        Ok(out)
    }
    fn u32(&mut self) -> Result<u32, CdrError> {
        self.align(4);
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    fn str(&mut self) -> Result<&'a str, CdrError> {
        let text = self.raw_str()?;
        std::str::from_utf8(text).map_err(|e| CdrError(format!("string is not UTF-8: {e}")))
    }
    /// A string's bytes, its terminating NUL left out, not yet checked to be UTF-8.
    fn raw_str(&mut self) -> Result<&'a [u8], CdrError> {
        let n = self.u32()? as usize;
        let bytes = self.take(n)?;
        Ok(bytes.strip_suffix(&[0]).unwrap_or(bytes))
    }
    fn string(&mut self) -> Result<String, CdrError> {
        self.str().map(str::to_string)
    }
    fn f64s(&mut self) -> Result<Vec<f64>, CdrError> {
        let n = self.u32()? as usize;
        if n > 0 {
            self.align(8);
        }
        let bytes = self.take(n.checked_mul(8).ok_or_else(|| CdrError("sequence too long".into()))?)?;
        Ok(bytes.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))).collect())
    }
}

/// Encodes a JointState as CDR.
pub fn encode_joint_state(m: &JointState) -> Vec<u8> {
    let mut w = Writer::new(64 + m.name.iter().map(|n| n.len() + 8).sum::<usize>() + 24 * m.position.len() + 16);
    w.u32(m.sec as u32);
    w.u32(m.nanosec);
    w.string(&m.frame_id);
    w.u32(m.name.len() as u32);
    for n in m.name.iter() {
        w.string(n);
    }
    w.f64s(&m.position);
    w.f64s(&m.velocity);
    w.f64s(&m.effort);
    w.0
}

/// One point of a `trajectory_msgs/msg/JointTrajectory`: values per joint and its time from the start [ns].
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryPoint {
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
    pub time_from_start_ns: u64,
}

/// Encodes a JointTrajectory (zero stamp, empty frame, no efforts) of the joints `names` as CDR.
pub fn encode_joint_trajectory(names: &[String], points: &[TrajectoryPoint]) -> Vec<u8> {
    let n = names.len();
    let mut w = Writer::new(64 + names.iter().map(|s| s.len() + 8).sum::<usize>() + points.len() * (24 * n + 32));
    w.u32(0);
    w.u32(0);
    w.string("");
    w.u32(n as u32);
    for name in names {
        w.string(name);
    }
    w.u32(points.len() as u32);
    for p in points {
        w.f64s(&p.positions);
        w.f64s(&p.velocities);
        w.f64s(&p.accelerations);
        w.f64s(&[]);
        w.u32((p.time_from_start_ns / 1_000_000_000) as u32);
        w.u32((p.time_from_start_ns % 1_000_000_000) as u32);
    }
    w.0
}

/// Decodes a CDR JointState.
pub fn decode_joint_state(buf: &[u8]) -> Result<JointState, CdrError> {
    JointStateDecoder::default().decode(buf)
}

/// Decodes the `sensor_msgs/msg/JointState` messages of a log one after another, the messages that name the same
/// joints as the one before sharing its name list: a driver names the same joints every time, and an hour's log at
/// 1 kHz would otherwise hold millions of copies of them.
#[derive(Debug, Default)]
pub struct JointStateDecoder {
    names: Option<std::sync::Arc<[String]>>,
}

impl JointStateDecoder {
    pub fn decode(&mut self, buf: &[u8]) -> Result<JointState, CdrError> {
        let mut r = Reader::new(buf)?;
        let sec = r.u32()? as i32;
        let nanosec = r.u32()?;
        let frame_id = r.string()?;
        let count = r.u32()? as usize;
        if count > buf.len() {
            return Err(CdrError(format!("{count} joint names cannot fit in {} bytes", buf.len())));
        }
        // The previous message's names, byte for byte (a UTF-8 string equal to a valid one is valid), before any
        // are parsed: an hour's log repeats them millions of times.
        let start = r.pos;
        let name = match &self.names {
            Some(last) if last.len() == count && last.iter().all(|n| r.raw_str().is_ok_and(|b| b == n.as_bytes())) => {
                last.clone()
            }
            _ => {
                r.pos = start;
                let fresh: std::sync::Arc<[String]> =
                    (0..count).map(|_| r.str().map(str::to_string)).collect::<Result<_, _>>()?;
                self.names = Some(fresh.clone());
                fresh
            }
        };
        Ok(JointState { sec, nanosec, frame_id, name, position: r.f64s()?, velocity: r.f64s()?, effort: r.f64s()? })
    }
}

/// Encodes a `std_msgs/msg/String`.
pub fn encode_string(s: &str) -> Vec<u8> {
    let mut w = Writer::new(s.len() + 9);
    w.string(s);
    w.0
}

/// Decodes a `std_msgs/msg/String`.
pub fn decode_string(buf: &[u8]) -> Result<String, CdrError> {
    Reader::new(buf)?.string()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the worker writes, the readers read back; a family's record says so and a generator's does not; a record
    /// missing a field or holding a non-number names no job (a damaged or foreign shard), rather than a wrong one.
    #[test]
    fn a_job_record_reads_back_the_job_it_was_written_for() {
        let job = Job { seed: 11, robot: 1_000_000, trajectory: 15 };
        let generator = JobRecord {
            job,
            engine: "native".into(),
            dt: 1e-3,
            source: RobotSource::Generator { version: "3".into() },
        };
        let written = generator.to_metadata();
        assert_eq!(JobRecord::job_of(&written), Some(job));
        assert_eq!(written["dt"], "0.001");
        assert!(!JobRecord::is_family(&written));
        let family = JobRecord { source: RobotSource::Family { urdf_hash: "abc".into() }, ..generator };
        assert!(JobRecord::is_family(&family.to_metadata()));
        for (key, value) in [("seed", None), ("robot", Some("x")), ("trajectory", Some("4294967296"))] {
            let mut damaged = written.clone();
            match value {
                None => drop(damaged.remove(key)),
                Some(v) => drop(damaged.insert(key.to_string(), v.to_string())),
            }
            assert_eq!(JobRecord::job_of(&damaged), None, "{key}: {value:?}");
        }
    }

    #[test]
    fn joint_state_bytes_follow_the_cdr_alignment_rules() {
        // Worked example: frame "base" (5 bytes with NUL) leaves the name count at offset 24; "j0\0" and "j1\0" are
        // padded to 4; the position count sits at 44 and its doubles are aligned to 8 from the header's end (48 -> 52).
        let m = JointState {
            sec: 1,
            nanosec: 500,
            frame_id: "base".into(),
            name: vec!["j0".into(), "j1".into()].into(),
            position: vec![1.0, 2.0],
            velocity: vec![],
            effort: vec![0.5, -0.5],
        };
        let b = encode_joint_state(&m);
        assert_eq!(b.len(), 92);
        assert_eq!(&b[..12], &[0, 1, 0, 0, 1, 0, 0, 0, 0xf4, 1, 0, 0]);
        assert_eq!(&b[12..24], &[5, 0, 0, 0, b'b', b'a', b's', b'e', 0, 0, 0, 0]);
        assert_eq!(&b[44..52], &[2, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(&b[52..60], &1.0f64.to_le_bytes());
        assert_eq!(&b[68..76], &[0, 0, 0, 0, 2, 0, 0, 0]);
        assert_eq!(&b[84..92], &(-0.5f64).to_le_bytes());
        assert_eq!(decode_joint_state(&b).unwrap(), m);
    }

    #[test]
    fn a_decoder_shares_names_that_repeat_and_notices_names_that_change() {
        let message = |names: &[&str]| {
            let m = JointState {
                name: names.iter().map(|n| n.to_string()).collect(),
                position: vec![0.5; names.len()],
                ..Default::default()
            };
            encode_joint_state(&m)
        };
        let mut decoder = JointStateDecoder::default();
        let first = decoder.decode(&message(&["j0", "j1"])).unwrap();
        let again = decoder.decode(&message(&["j0", "j1"])).unwrap();
        assert!(std::sync::Arc::ptr_eq(&first.name, &again.name));
        // The same count and length, one byte apart; then one name fewer.
        let changed = decoder.decode(&message(&["j0", "j2"])).unwrap();
        assert_eq!(&changed.name[..], ["j0", "j2"]);
        let fewer = decoder.decode(&message(&["j0"])).unwrap();
        assert_eq!(&fewer.name[..], ["j0"]);
        assert_eq!(fewer.position, [0.5]);
        // A name that is not UTF-8 is refused even right after a valid list of the same length.
        let mut bad = message(&["j0", "j1"]);
        let at = bad.windows(3).rposition(|w| w == b"j1\0").unwrap();
        bad[at] = 0xff;
        assert!(decoder.decode(&bad).is_err());
    }

    #[test]
    fn file_names_give_back_their_robot() {
        assert_eq!(file_name(315, 6, "native"), "r000315-t06-native.mcap");
        assert_eq!(robot_of_file_name(&file_name(315, 6, "native")), Some(315));
        assert_eq!(robot_of_file_name(&file_name(1_234_567, 15, "rapier")), Some(1_234_567));
        for other in ["r000315-t06-native.mcap.tmp", "robot.mcap", "r-t06-native.mcap", "r000315-t06-.mcap", "bag.mcap"]
        {
            assert_eq!(robot_of_file_name(other), None, "{other}");
        }
    }

    #[test]
    fn strings_round_trip_and_bad_input_is_an_error() {
        let b = encode_string("hi");
        assert_eq!(b, [0, 1, 0, 0, 3, 0, 0, 0, b'h', b'i', 0]);
        assert_eq!(decode_string(&b).unwrap(), "hi");
        assert!(decode_string(&b[..6]).is_err());
        assert!(decode_string(&[0, 0, 0, 0, 1, 0, 0, 0]).is_err(), "big-endian is refused");
        let m = JointState { name: vec!["a".into(); 6].into(), position: vec![0.1; 6], ..Default::default() };
        let full = encode_joint_state(&m);
        for cut in 0..full.len() {
            assert!(decode_joint_state(&full[..cut]).is_err(), "cut at {cut}");
        }
    }
}
