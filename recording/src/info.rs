//! What a log holds, at a glance (`dynforge info`, after `ros2 bag info`): its joint-state stream, its robot and,
//! for a dataset shard, its job and labels. It reads the file as identification would, so a log `info` describes
//! without complaint is one `identify` and `estimate` accept as far as the file goes.

use std::path::{Path, PathBuf};

use dynforge_proto::shard::{META_JOB, META_LABELS};

use dynforge_shard::Bag;

use crate::error::ReadError;
use crate::read::{Gap, Reading, first_gap, read_bag};

/// A log's summary.
#[derive(Debug, Clone)]
pub struct Info {
    pub file: String,
    pub bytes: u64,
    pub joint_states: usize,
    /// First and last header stamp [s].
    pub span: Option<(f64, f64)>,
    /// Joint names of the first message.
    pub joints: Vec<String>,
    /// The robot's name and moving joints, from `/robot_description`; or why it could not be read.
    pub robot: Option<Result<(String, usize), dynforge_robot::model::ModelProblem>>,
    /// Metadata records: name -> (key, value), in file order of keys.
    pub metadata: Vec<(String, Vec<(String, String)>)>,
    /// The first jump of the stamps by more than a few sampling periods, and how many there are.
    pub gaps: Option<(Gap, usize)>,
    /// What vouches for the file's content.
    pub check: Check,
    /// The logger's stale repeats and missed ticks (when every message names the same joints).
    pub clock: Option<crate::samples::Clock>,
}

/// What vouches for a log's content: a shard's labels are outside the chunks the MCAP reader checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// Its data-section CRC matched.
    Crc,
    /// It hashes to what its run directory's ledger records (checked also when it has a CRC).
    Ledger,
    /// Nothing: no CRC (MCAP allows that), and no ledger records it.
    None,
}

impl Info {
    /// Reads `path`: an MCAP or sqlite3 file, a rosbag2 directory holding them, or a table read as `how` says.
    pub fn of(path: &Path, how: &Reading) -> Result<Info, ReadError> {
        let (files, bag) = read_bag(path, how)?;
        Info::of_bag(path, &files, &bag)
    }

    /// [`Info::of`] of a log already read: its `files` and their messages `bag`.
    pub fn of_bag(path: &Path, files: &[PathBuf], bag: &Bag) -> Result<Info, ReadError> {
        let check = match crate::dataset::recorded_hash(&files[0]) {
            Some(recorded) if files.len() == 1 => {
                let bytes = std::fs::read(&files[0])
                    .map_err(|e| ReadError::Content { file: files[0].display().to_string(), problem: e.to_string() })?;
                crate::dataset::check_recorded(&bytes, &files[0], recorded)?;
                Check::Ledger
            }
            _ if bag.crc_checked => Check::Crc,
            _ => Check::None,
        };
        let mut sorted: Vec<i64> = bag.joint_states.iter().map(|m| m.stamp_ns()).collect();
        sorted.sort_unstable();
        sorted.dedup();
        let first = sorted.first().copied().unwrap_or(0);
        let t: Vec<f64> = sorted.iter().map(|&s| (s - first) as f64 * 1e-9).collect();
        let gaps = first_gap(&t).map(|g| {
            let n = t.windows(2).filter(|w| w[1] - w[0] > crate::samples::GAP_PERIODS * g.period).count();
            (g, n)
        });
        let clock = bag
            .joint_states
            .first()
            .and_then(|m| Some(crate::samples::from_bag_any_velocity(bag, &m.name, &files[0]).ok()?.0.clock()));
        let bytes = files.iter().map(|f| std::fs::metadata(f).map_or(0, |m| m.len())).sum();
        let file = if files.len() == 1 { files[0].clone() } else { path.to_path_buf() };
        let stamps: Vec<f64> = bag.joint_states.iter().map(|m| m.stamp_ns() as f64 * 1e-9).collect();
        let span = stamps.iter().copied().reduce(f64::min).zip(stamps.iter().copied().reduce(f64::max));
        let robot = bag.robot_description.as_ref().map(|text| {
            dynforge_robot::urdf::parse(text, "/robot_description")
                .map(|m| (m.name().to_string(), m.dof()))
                .map_err(|e| e.problem)
        });
        Ok(Info {
            file: file.display().to_string(),
            bytes,
            joint_states: bag.joint_states.len(),
            span,
            joints: bag.joint_states.first().map(|m| m.name.to_vec()).unwrap_or_default(),
            robot,
            metadata: bag.metadata.iter().map(|(k, v)| (k.clone(), v.clone().into_iter().collect())).collect(),
            gaps,
            check,
            clock,
        })
    }
}

impl std::fmt::Display for Info {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "File:        {} ({:.1} MB)", self.file, self.bytes as f64 / 1e6)?;
        match self.span {
            Some((a, b)) => {
                writeln!(f, "Duration:    {:.3} s (stamps {a:.6} .. {b:.6} s)", b - a)?;
                match self.gaps {
                    // Messages over the whole span would count the gaps as time sampled.
                    Some((g, _)) => writeln!(
                        f,
                        "/joint_states: {} messages, {:.1} Hz (median period)",
                        self.joint_states,
                        1.0 / g.period
                    )?,
                    None if b > a => writeln!(
                        f,
                        "/joint_states: {} messages, {:.1} Hz mean",
                        self.joint_states,
                        (self.joint_states as f64 - 1.0) / (b - a)
                    )?,
                    None => writeln!(f, "/joint_states: {} message(s) at one stamp: no rate", self.joint_states)?,
                }
            }
            None => writeln!(f, "/joint_states: none")?,
        }
        if let Some((g, n)) = self.gaps {
            writeln!(
                f,
                "Gaps:        {n} (the first {:.3} s long, after t = {:.3} s): `identify` reads the stretches apart; \
                 `estimate` and `train` refuse the log",
                g.length, g.after
            )?;
        }
        if let Some(c) = self.clock.filter(|c| c.repeats + c.skipped > 0) {
            writeln!(
                f,
                "Clock:       {} stale sample(s) (exact repeats of the one before while moving: left out), {} missed \
                 tick(s) (steps of two or more periods: interpolated over)",
                c.repeats, c.skipped
            )?;
        }
        let check = match self.check {
            Check::Crc => "data-section CRC matches",
            Check::Ledger => "content hash matches its run's ledger",
            Check::None => "nothing: no data-section CRC and no run ledger records it (labels are not trusted)",
        };
        writeln!(f, "Checked:     {check}")?;
        writeln!(f, "Joints:      {}", if self.joints.is_empty() { "-".into() } else { self.joints.join(", ") })?;
        match &self.robot {
            Some(Ok((name, dof))) => writeln!(f, "Robot:       {name} ({dof} moving joints, from /robot_description)")?,
            Some(Err(why)) => writeln!(f, "Robot:       /robot_description unreadable: {why}")?,
            None => writeln!(f, "Robot:       no /robot_description (give the URDF to identify or estimate)")?,
        }
        for (name, entries) in &self.metadata {
            let title = match name.as_str() {
                META_JOB => "Job",
                META_LABELS => "Labels",
                crate::table::META_TABLE => "Table (the column map as read)",
                other => other,
            };
            let short = |v: &str| match v.parse::<f64>() {
                Ok(x) if x != 0.0 && x.abs() < 1e-2 => format!("{x:.4e}"),
                Ok(x) if x.fract() != 0.0 => format!("{x:.5}"),
                _ => v.to_string(),
            };
            let text: Vec<String> = entries.iter().map(|(k, v)| format!("{k} {}", short(v))).collect();
            writeln!(f, "{title}:")?;
            for line in text.chunks(6) {
                writeln!(f, "  {}", line.join(", "))?;
            }
        }
        Ok(())
    }
}
