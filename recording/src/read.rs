//! A recording read whole: the robot, its trajectory on the uniform grid, and the labels of a dataset shard.

use std::path::{Path, PathBuf};

use dynforge_proto::shard::{JobRecord, META_JOB, META_LABELS};
use dynforge_proto::{LABELS, NUM_LABELS};
use dynforge_robot::{Model, urdf};

use crate::error::ReadError;
use crate::resample::resample;
use crate::samples::{GAP_PERIODS, JointTrajectory, from_bag};

/// Period of the uniform grid recordings are put on [s]: the simulator's and the paper's 1 kHz.
pub const GRID_DT: f64 = 1e-3;

/// A recording ready for identification and windowing: the robot, its trajectory on the [`GRID_DT`] grid, and its
/// labels if it has them.
#[derive(Debug, Clone)]
pub struct Recording {
    pub path: PathBuf,
    pub model: Model,
    pub trajectory: JointTrajectory,
    /// The 38 labels (dataset shards; a user's bag has none).
    pub labels: Option<[f64; NUM_LABELS]>,
    /// Robot id within its dataset (shards only).
    pub robot: Option<u64>,
    /// Which of its robot's trajectories this is (shards only): with the robot, what names a recording in a split
    /// that holds out trajectories or windows.
    pub trajectory_index: Option<u32>,
}

/// How a log is read beyond what its files say: a table's column map, the drives' gains, joints to weld.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Reading {
    /// The column map of logs that are tables ([`crate::table`]).
    pub columns: Option<crate::table::ColumnMap>,
    /// Joint torque (force) per unit of the logged effort, for each of the URDF's moving joints in order: a driver
    /// that logs motor currents (`--gains`).
    pub gains: Option<Vec<f64>>,
    /// Joints welded at their mean logged position (`--fix`).
    pub fixed: Vec<String>,
}

impl Reading {
    /// Joints `fixed` welded, and nothing else asked.
    pub fn welding(fixed: &[String]) -> Reading {
        Reading { fixed: fixed.to_vec(), ..Reading::default() }
    }
}

/// The files of a log given as a file or as a rosbag2 directory (`metadata.yaml` beside `NAME_0.mcap`,
/// `NAME_1.mcap`, ... or `NAME_0.db3`, ... when the recorder split it), in recording order: as `metadata.yaml` lists
/// them, else by the number the recorder appends.
pub fn log_files(path: &Path) -> Result<Vec<PathBuf>, ReadError> {
    if !path.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let content = |problem: String| ReadError::Content { file: path.display().to_string(), problem };
    let listing: Vec<PathBuf> =
        std::fs::read_dir(path).map_err(|e| content(e.to_string()))?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    let with = |extension: &str| -> Vec<PathBuf> {
        listing.iter().filter(|p| p.extension().is_some_and(|x| x == extension)).cloned().collect()
    };
    let mut files = with("mcap");
    if files.is_empty() {
        files = with(crate::sqlite::EXTENSION);
    }
    if files.is_empty() {
        return Err(content(
            "a directory with no .mcap or .db3 file (a log is an MCAP file, a rosbag2 directory, or a table with \
             --columns)"
                .into(),
        ));
    }
    let listed = std::fs::read_to_string(path.join("metadata.yaml")).unwrap_or_default();
    let order = |p: &PathBuf| {
        let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let stem = p.file_stem().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let number = stem.rsplit('_').next().and_then(|n| n.parse::<u64>().ok());
        (listed.find(&name).unwrap_or(usize::MAX), number.unwrap_or(u64::MAX), name)
    };
    files.sort_by_key(order);
    Ok(files)
}

/// The bag of a log (a file, or every file of a rosbag2 directory joined: messages in recording order, the
/// `/robot_description` of whichever file has one, metadata of all; CRC-checked if every file was): an MCAP file,
/// a rosbag2 sqlite3 file, or a table read by `how`'s column map.
pub fn read_bag(path: &Path, how: &Reading) -> Result<(Vec<PathBuf>, dynforge_shard::Bag), ReadError> {
    let files = log_files(path)?;
    let first = &files[0];
    let bag = if first.extension().is_some_and(|x| x == crate::sqlite::EXTENSION) {
        crate::sqlite::read_joined(&files)?
    } else if crate::table::is_table(first) {
        let map = how.columns.as_ref().ok_or_else(|| ReadError::Content {
            file: first.display().to_string(),
            problem: "a table: give its column map (--columns MAP.toml: which column is time, and each joint's \
                      position, velocity and effort)"
                .into(),
        })?;
        crate::table::read(first, map)?
    } else {
        dynforge_shard::read_joined(&files)?
    };
    Ok((files, bag))
}

/// An error unless writing `out` leaves every input in `inputs` (log files or rosbag2 directories) as it is: `out` is
/// none of their files (however the paths are spelt: `./log.mcap`, a link), and not inside one's directory.
pub fn check_not_an_input(out: &Path, inputs: &[PathBuf]) -> Result<(), ReadError> {
    use dynforge_proto::run_dir::resolve;
    let target = resolve(out);
    for input in inputs {
        let input = resolve(input);
        if target == input || (input.is_dir() && target.starts_with(&input)) {
            return Err(ReadError::Content {
                file: out.display().to_string(),
                problem: format!(
                    "this output would overwrite the input {} (or a file of it): choose another --out",
                    input.display()
                ),
            });
        }
    }
    Ok(())
}

/// The URDF document of the robot of `log`: the file `urdf` when given, else the log's `/robot_description`; with the
/// name to report it by. What `estimate` and `identify` write their results into.
pub fn robot_document(urdf: Option<&Path>, log: &Path) -> Result<(String, String), ReadError> {
    if let Some(path) = urdf {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ReadError::Content { file: path.display().to_string(), problem: e.to_string() })?;
        return Ok((text, path.display().to_string()));
    }
    let (files, bag) = read_bag(log, &Reading::default())?;
    let file = files[0].display().to_string();
    let text = bag.robot_description.ok_or_else(|| ReadError::Content {
        file: file.clone(),
        problem: "no /robot_description in the file: give the robot's URDF".into(),
    })?;
    Ok((text, format!("{file} (/robot_description)")))
}

/// Reads a shard or bag (a file, or a rosbag2 directory); the robot comes from its `/robot_description` unless
/// `model` is given.
pub fn read(path: &Path, model: Option<&Model>) -> Result<Recording, ReadError> {
    let (files, bag) = read_bag(path, &Reading::default())?;
    recording_of(&files[0], &bag, model)
}

/// [`read`] of a shard already in memory (`bytes`, the content of the file `path`), for readers that check the bytes
/// themselves (against a run's ledger) before trusting them.
pub fn read_shard_bytes(bytes: &[u8], path: &Path, model: Option<&Model>) -> Result<Recording, ReadError> {
    recording_of(path, &dynforge_shard::read_bytes(bytes, path)?, model)
}

/// The recording of `bag`, read from `path` (its first file): [`read`] of a log already read.
pub fn recording_of(path: &Path, bag: &dynforge_shard::Bag, model: Option<&Model>) -> Result<Recording, ReadError> {
    let file = path.display().to_string();
    let content = |problem: String| ReadError::Content { file: file.clone(), problem };
    let model = match (model, &bag.robot_description) {
        (Some(m), _) => m.clone(),
        (None, Some(text)) => {
            urdf::parse(text, &format!("{file} (/robot_description)")).map_err(|e| content(e.to_string()))?
        }
        (None, None) => return Err(content("no /robot_description in the file: give the robot's URDF".into())),
    };
    let names: Vec<String> = model.joints().iter().map(|j| j.name.clone()).collect();
    let samples = from_bag(bag, &names, path)?;
    // Put on the grid whole, a stretch between two stamps a day apart would be 86 million interpolated samples.
    if let Some(gap) = first_gap(&samples.t) {
        return Err(content(format!(
            "the stamps jump by {:.3} s after t = {:.3} s (more than {GAP_PERIODS} sampling periods of {:.3} ms): a \
             gap in the recording, which this command reads as one continuous motion. Cut the log at its gaps, or \
             calibrate with `dynforge identify`, which reads the stretches between gaps apart",
            gap.length,
            gap.after,
            gap.period * 1e3
        )));
    }
    let trajectory = resample(&samples, GRID_DT);
    let labels = match bag.metadata.get(META_LABELS) {
        // The labels are outside the chunks the reader checks: only the data-section CRC vouches for them.
        Some(_) if !bag.crc_checked => {
            return Err(content(
                "it carries dataset labels but no data-section CRC (0), so nothing shows they are as written (every \
                 shard dynforge writes has one): a shard rewritten by another tool, or edited"
                    .into(),
            ));
        }
        Some(map) => {
            let mut y = [0.0; NUM_LABELS];
            for (v, l) in y.iter_mut().zip(LABELS.iter()) {
                *v = map
                    .get(l.name)
                    .and_then(|s| s.parse().ok())
                    .ok_or_else(|| content(format!("label {} missing", l.name)))?;
            }
            Some(y)
        }
        None => None,
    };
    let job = bag.metadata.get(META_JOB).and_then(JobRecord::job_of);
    let (robot, trajectory_index) = (job.map(|j| j.robot), job.map(|j| j.trajectory));
    Ok(Recording { path: path.to_path_buf(), model, trajectory, labels, robot, trajectory_index })
}

/// A jump in a recording's stamps: more than [`GAP_PERIODS`] times its median sampling period.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gap {
    /// The stamp it follows [s, from the first], its length [s], and the median period [s].
    pub after: f64,
    pub length: f64,
    pub period: f64,
}

/// The first gap of the sample times `t` (increasing), if any.
pub fn first_gap(t: &[f64]) -> Option<Gap> {
    let steps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let period = crate::samples::median(&mut steps.clone())?;
    steps.iter().position(|&s| s > GAP_PERIODS * period).map(|i| Gap { after: t[i], length: steps[i], period })
}

impl Recording {
    /// Seconds of motion on the grid.
    pub fn seconds(&self) -> f64 {
        self.trajectory.len() as f64 * GRID_DT
    }
}
