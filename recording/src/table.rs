//! Logs written as tables (CSV, TSV, whitespace-separated: what RTDE, MATLAB and most lab loggers write), read by a
//! declared column map, never by guessing what a column holds. The map is a small TOML file:
//!
//! ```toml
//! delimiter = "comma"         # comma, tab, semicolon or whitespace (default: from the extension)
//! header = false              # whether the first row (after skip_rows) names the columns
//! skip_rows = 0               # rows before the data (or the header)
//! bad_rows = "error"          # or "skip": rows of the wrong width or with a non-number are left out and counted
//! time = { column = 1, unit = "s" }    # s, ms, us or ns
//!
//! [joints.shoulder_pan_joint]  # a URDF joint
//! position = 2                 # columns count from 1, or name a header's column ("q1")
//! velocity = 8                 # optional (every joint or none)
//! current = 14                 # or `effort = 14` for a torque [N m] or force [N]
//! gain = 10.0                  # joint torque per unit of the column: required for a current (or --gains)
//! ```
//!
//! The table becomes the bag a driver would have recorded: one `sensor_msgs/msg/JointState` per row, the effort in
//! joint torque, so every command reads it as it reads a bag.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use dynforge_proto::shard::JointState;
use dynforge_shard::{Bag, Metadata};

use crate::error::ReadError;

/// Extensions read as tables.
pub const EXTENSIONS: [&str; 4] = ["csv", "tsv", "txt", "dat"];

/// Whether `path` names a table by its extension.
pub fn is_table(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// The metadata record that says how a table was read (`info` prints it).
pub const META_TABLE: &str = "table";

/// What is wrong with a column map, before or while a table is read by it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MapProblem {
    #[error("no [joints.NAME] table: name each URDF joint's columns")]
    NoJoints,
    #[error("velocity is given for some joints and not for others: give it for every joint or none")]
    SomeVelocities,
    #[error("column 0: columns count from 1")]
    ColumnZero,
    #[error("column '{0}' is named, but header = false: number it, or set header")]
    NamedWithoutHeader(String),
    #[error("joint '{0}': effort and current both given; give one")]
    EffortAndCurrent(String),
    #[error("joint '{0}': no effort or current column")]
    NoEffort(String),
    #[error("joint '{joint}': gain {gain} is not a finite, non-zero number")]
    Gain { joint: String, gain: f64 },
    #[error("joint '{0}': a gain in the column map and in --gains")]
    GainTwice(String),
    #[error(
        "joint '{0}': its column is a current, and no gain turns it into a torque (give --gains, or gain = ... in the \
         column map)"
    )]
    NoGain(String),
    #[error("the header has no column '{name}' (it has {header:?})")]
    NotInHeader { name: String, header: Vec<String> },
}

/// Why a row of a table gives no joint state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum RowProblem {
    #[error("column {column}: '{field}' is not a number")]
    NotANumber { column: usize, field: String },
    #[error("column {column}: {value} is not a finite number")]
    NotFinite { column: usize, value: f64 },
    #[error("{count} column(s), the column map reads column {width}")]
    Narrow { count: usize, width: usize },
    #[error("time {0} is not a time")]
    Time(f64),
    #[error("the time goes backwards ({at} after {before})")]
    Backwards { at: f64, before: f64 },
}

/// A table's column map: which column holds what (see the module documentation).
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColumnMap {
    #[serde(default)]
    pub delimiter: Option<Delimiter>,
    #[serde(default)]
    pub header: bool,
    #[serde(default)]
    pub skip_rows: usize,
    #[serde(default)]
    pub bad_rows: BadRows,
    pub time: TimeColumn,
    /// Each URDF joint's columns, by joint name.
    pub joints: BTreeMap<String, JointColumns>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Delimiter {
    Comma,
    Tab,
    Semicolon,
    /// Any run of spaces and tabs.
    Whitespace,
}

/// What to do with a row that cannot be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BadRows {
    /// Refuse the table, naming the file and the line.
    #[default]
    Error,
    /// Leave the row out and count it.
    Skip,
}

/// A column: its number (from 1) or its header's name.
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize)]
#[serde(untagged)]
pub enum Column {
    Number(usize),
    Name(String),
}

impl std::fmt::Display for Column {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Column::Number(n) => write!(f, "{n}"),
            Column::Name(name) => write!(f, "'{name}'"),
        }
    }
}

#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeColumn {
    pub column: Column,
    #[serde(default)]
    pub unit: TimeUnit,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
pub enum TimeUnit {
    #[default]
    #[serde(rename = "s")]
    Seconds,
    #[serde(rename = "ms")]
    Milliseconds,
    #[serde(rename = "us")]
    Microseconds,
    #[serde(rename = "ns")]
    Nanoseconds,
}

impl TimeUnit {
    fn nanoseconds(self) -> f64 {
        match self {
            TimeUnit::Seconds => 1e9,
            TimeUnit::Milliseconds => 1e6,
            TimeUnit::Microseconds => 1e3,
            TimeUnit::Nanoseconds => 1.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointColumns {
    pub position: Column,
    #[serde(default)]
    pub velocity: Option<Column>,
    /// The joint's torque [N m] (force [N] for a prismatic joint), or with `gain`, a quantity proportional to it.
    #[serde(default)]
    pub effort: Option<Column>,
    /// The motor's current: a torque only through `gain`.
    #[serde(default)]
    pub current: Option<Column>,
    /// Joint torque per unit of the effort or current column.
    #[serde(default)]
    pub gain: Option<f64>,
}

impl ColumnMap {
    /// Reads the map file `path`.
    pub fn read(path: &Path) -> Result<ColumnMap, ReadError> {
        let content = |problem: String| ReadError::Content { file: path.display().to_string(), problem };
        let text = std::fs::read_to_string(path).map_err(|e| content(e.to_string()))?;
        let map: ColumnMap = toml::from_str(&text).map_err(|e| content(format!("not a column map: {e}")))?;
        map.check().map_err(|e| content(e.to_string()))?;
        Ok(map)
    }

    /// The map's own consistency, before any table is read.
    fn check(&self) -> Result<(), MapProblem> {
        if self.joints.is_empty() {
            return Err(MapProblem::NoJoints);
        }
        let with_velocity = self.joints.values().filter(|j| j.velocity.is_some()).count();
        if with_velocity != 0 && with_velocity != self.joints.len() {
            return Err(MapProblem::SomeVelocities);
        }
        let columns = std::iter::once(&self.time.column).chain(self.joints.values().flat_map(|j| {
            [Some(&j.position), j.velocity.as_ref(), j.effort.as_ref(), j.current.as_ref()].into_iter().flatten()
        }));
        for c in columns {
            match c {
                Column::Number(0) => return Err(MapProblem::ColumnZero),
                Column::Name(name) if !self.header => return Err(MapProblem::NamedWithoutHeader(name.clone())),
                _ => {}
            }
        }
        for (name, j) in &self.joints {
            match (&j.effort, &j.current) {
                (Some(_), Some(_)) => return Err(MapProblem::EffortAndCurrent(name.clone())),
                (None, None) => return Err(MapProblem::NoEffort(name.clone())),
                _ => {}
            }
            if let Some(g) = j.gain
                && !(g.is_finite() && g != 0.0)
            {
                return Err(MapProblem::Gain { joint: name.clone(), gain: g });
            }
        }
        Ok(())
    }

    /// An error unless every joint's effort becomes a torque exactly once: a current needs a gain, from the map or
    /// from `--gains` (`gains_given`), and a gain in both would be applied twice.
    pub fn check_gains(&self, gains_given: bool) -> Result<(), MapProblem> {
        for (name, j) in &self.joints {
            match (j.gain, gains_given) {
                (Some(_), true) => return Err(MapProblem::GainTwice(name.clone())),
                (None, false) if j.current.is_some() => return Err(MapProblem::NoGain(name.clone())),
                _ => {}
            }
        }
        Ok(())
    }

    fn delimiter_for(&self, path: &Path) -> Delimiter {
        self.delimiter.unwrap_or_else(|| match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("csv") => Delimiter::Comma,
            Some(e) if e.eq_ignore_ascii_case("tsv") => Delimiter::Tab,
            _ => Delimiter::Whitespace,
        })
    }
}

/// What one row gives: the time and each joint's values, as column indices from 0.
struct Layout {
    time: usize,
    scale: f64,
    position: Vec<usize>,
    velocity: Option<Vec<usize>>,
    effort: Vec<usize>,
    /// Joint torque per unit of each joint's effort column (1 for a torque without a gain).
    gain: Vec<f64>,
    /// The widest column read, plus one: a row narrower than that is torn.
    width: usize,
}

/// The table at `path` read by `map` as a bag of joint states, each joint's effort times its map's gain (a current
/// without one is read as it is: see [`ColumnMap::check_gains`]). Rows that cannot be read and time going backwards
/// are errors naming the line, or skipped and counted (the map's `bad_rows`); the count and the map as understood
/// are the bag's [`META_TABLE`] record.
pub fn read(path: &Path, map: &ColumnMap) -> Result<Bag, ReadError> {
    use std::io::{BufRead, Read};
    let file = path.display().to_string();
    let content = |problem: String| ReadError::Content { file: file.clone(), problem };
    let io = |e: std::io::Error| content(e.to_string());
    let mut reader = std::io::BufReader::with_capacity(1 << 20, std::fs::File::open(path).map_err(io)?);
    let delimiter = map.delimiter_for(path);
    // Lines before the data: the rows skipped, and the header.
    let mut line = String::new();
    for _ in 0..map.skip_rows + usize::from(map.header) {
        line.clear();
        if reader.read_line(&mut line).map_err(|e| content(format!("not text: {e}")))? == 0 {
            return Err(content("no header row".into()));
        }
    }
    let header: Vec<&str> = match map.header {
        true => fields(line.trim_end_matches(['\n', '\r']), delimiter).map(|f| f.trim().trim_matches('"')).collect(),
        false => Vec::new(),
    };
    let layout = layout(map, &header).map_err(|e| content(e.to_string()))?;
    let parser = RowParser::new(map, &layout, delimiter);
    let (mut joint_states, mut skipped, mut first_skipped) = (Vec::new(), 0usize, None::<String>);
    let mut last_ns = i64::MIN;
    let mut first_line = map.skip_rows + usize::from(map.header);
    // Blocks of whole lines, each parsed a piece per core, then taken in order: an hour's table is gigabytes of
    // text, never held whole.
    let mut block = Vec::with_capacity(BLOCK + (1 << 16));
    loop {
        block.clear();
        (&mut reader).take(BLOCK as u64).read_to_end(&mut block).map_err(io)?;
        if block.is_empty() {
            break;
        }
        if !block.ends_with(b"\n") {
            reader.read_until(b'\n', &mut block).map_err(io)?;
        }
        let text = std::str::from_utf8(&block).map_err(|e| {
            let line = first_line + 1 + block[..e.valid_up_to()].iter().filter(|&&b| b == b'\n').count();
            content(format!("line {line}: not text ({e})"))
        })?;
        let pieces = split_lines(text, first_line);
        first_line += text.bytes().filter(|&b| b == b'\n').count();
        let parsed = dynforge_proto::parallel::map_in_order(&pieces, |(piece, first)| parser.parse(piece, *first));
        for (index, row) in parsed.into_iter().flatten() {
            let row = row.and_then(|m| match m.stamp_ns() {
                ns if ns < last_ns => {
                    let unit = |ns: i64| ns as f64 / layout.scale;
                    Err(RowProblem::Backwards { at: unit(ns), before: unit(last_ns) })
                }
                _ => Ok(m),
            });
            match row {
                Ok(m) => {
                    last_ns = m.stamp_ns();
                    joint_states.push(m);
                }
                Err(problem) if map.bad_rows == BadRows::Skip => {
                    skipped += 1;
                    first_skipped.get_or_insert_with(|| format!("line {}: {problem}", index + 1));
                }
                Err(problem) => {
                    return Err(content(format!(
                        "line {}: {problem} (set bad_rows = \"skip\" in the column map to leave such rows out)",
                        index + 1
                    )));
                }
            }
        }
    }
    if joint_states.is_empty() {
        return Err(content("no data row".into()));
    }
    let mut record = BTreeMap::from([
        ("rows".to_string(), joint_states.len().to_string()),
        ("skipped_rows".to_string(), skipped.to_string()),
        ("columns".to_string(), understood(map, &layout)),
    ]);
    if let Some(first) = first_skipped {
        record.insert("first_skipped".into(), first);
    }
    let metadata: Metadata = [(META_TABLE.to_string(), record)].into();
    Ok(Bag { robot_description: None, joint_states, metadata, crc_checked: false })
}

/// Bytes of a table read at a time (then to the end of its line).
const BLOCK: usize = 16 << 20;

/// `text` (whole lines, the first of them the table's line `first`, counted from 0) cut at line ends into a piece
/// per core, each with the number of its first line.
fn split_lines(text: &str, first: usize) -> Vec<(&str, usize)> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut pieces = Vec::with_capacity(cores);
    let (mut rest, mut line) = (text, first);
    while !rest.is_empty() {
        let want = (text.len() / cores).max(1).min(rest.len());
        // Just after the first line end at or past the share (a byte search: `want` may fall inside a character).
        let cut = rest.as_bytes()[want - 1..].iter().position(|&b| b == b'\n').map_or(rest.len(), |at| want + at);
        let (piece, after) = rest.split_at(cut);
        pieces.push((piece, line));
        line += piece.bytes().filter(|&b| b == b'\n').count();
        rest = after;
    }
    pieces
}

/// What a row of the table gives, by the map.
struct RowParser<'a> {
    layout: &'a Layout,
    delimiter: Delimiter,
    names: Arc<[String]>,
    /// Which columns up to the widest one read are read (the others are not parsed).
    wanted: Vec<bool>,
}

impl<'a> RowParser<'a> {
    fn new(map: &ColumnMap, layout: &'a Layout, delimiter: Delimiter) -> Self {
        let mut wanted = vec![false; layout.width];
        for c in std::iter::once(layout.time)
            .chain(layout.position.iter().copied())
            .chain(layout.velocity.iter().flatten().copied())
            .chain(layout.effort.iter().copied())
        {
            wanted[c] = true;
        }
        RowParser { layout, delimiter, names: map.joints.keys().cloned().collect(), wanted }
    }

    /// The rows of `piece` (its first line the table's line `first`), blank lines left out: each with its line
    /// number, and its joint state or why it has none.
    fn parse(&self, piece: &str, first: usize) -> Vec<(usize, Result<JointState, RowProblem>)> {
        let layout = self.layout;
        let mut values = vec![0.0; layout.width];
        let mut out = Vec::with_capacity(piece.len() / 64);
        for (k, line) in piece.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let row = parse_row(line, self.delimiter, &self.wanted, &mut values).and_then(|()| {
                let t = values[layout.time] * layout.scale;
                if !(t.is_finite() && t.abs() < 9.2e18) {
                    return Err(RowProblem::Time(values[layout.time]));
                }
                let ns = t.round() as i64;
                let pick = |columns: &[usize], gain: Option<&[f64]>| -> Vec<f64> {
                    columns.iter().enumerate().map(|(j, &c)| values[c] * gain.map_or(1.0, |g| g[j])).collect()
                };
                Ok(JointState {
                    sec: ns.div_euclid(1_000_000_000) as i32,
                    nanosec: ns.rem_euclid(1_000_000_000) as u32,
                    frame_id: String::new(),
                    name: self.names.clone(),
                    position: pick(&layout.position, None),
                    velocity: layout.velocity.as_deref().map_or_else(Vec::new, |v| pick(v, None)),
                    effort: pick(&layout.effort, Some(&layout.gain)),
                })
            });
            out.push((first + k, row));
        }
        out
    }
}

/// The map's columns as indices into a row whose header is `header` (empty without one).
fn layout(map: &ColumnMap, header: &[&str]) -> Result<Layout, MapProblem> {
    let index = |c: &Column| -> Result<usize, MapProblem> {
        match c {
            Column::Number(n) => Ok(n - 1),
            Column::Name(name) => header.iter().position(|h| h == name).ok_or_else(|| MapProblem::NotInHeader {
                name: name.clone(),
                header: header.iter().map(|h| h.to_string()).collect(),
            }),
        }
    };
    let joints: Vec<(&String, &JointColumns)> = map.joints.iter().collect();
    let all = |f: &dyn Fn(&JointColumns) -> Option<&Column>| -> Result<Vec<usize>, MapProblem> {
        joints.iter().map(|(_, j)| index(f(j).expect("checked with the map"))).collect()
    };
    let gain = joints.iter().map(|(_, j)| j.gain.unwrap_or(1.0)).collect();
    let position = all(&|j| Some(&j.position))?;
    let velocity = match joints.iter().all(|(_, j)| j.velocity.is_some()) {
        true => Some(all(&|j| j.velocity.as_ref())?),
        false => None,
    };
    let effort = all(&|j| j.effort.as_ref().or(j.current.as_ref()))?;
    let time = index(&map.time.column)?;
    let width = std::iter::once(time).chain(position.iter().chain(velocity.iter().flatten()).chain(&effort).copied());
    let width = width.max().unwrap_or(0) + 1;
    Ok(Layout { time, scale: map.time.unit.nanoseconds(), position, velocity, effort, gain, width })
}

/// The fields of `line`.
fn fields(line: &str, delimiter: Delimiter) -> Box<dyn Iterator<Item = &str> + '_> {
    match delimiter {
        Delimiter::Comma => Box::new(line.split(',')),
        Delimiter::Tab => Box::new(line.split('\t')),
        Delimiter::Semicolon => Box::new(line.split(';')),
        Delimiter::Whitespace => Box::new(line.split_ascii_whitespace()),
    }
}

/// The `wanted` fields of `line` parsed into `values` (the others are not parsed); why not, if the row is too narrow
/// or a wanted field is not a finite number.
fn parse_row(line: &str, delimiter: Delimiter, wanted: &[bool], values: &mut [f64]) -> Result<(), RowProblem> {
    let mut count = 0;
    for (c, field) in fields(line, delimiter).take(wanted.len()).enumerate() {
        count = c + 1;
        if wanted[c] {
            let v: f64 = field
                .trim()
                .parse()
                .map_err(|_| RowProblem::NotANumber { column: c + 1, field: field.trim().to_string() })?;
            if !v.is_finite() {
                return Err(RowProblem::NotFinite { column: c + 1, value: v });
            }
            values[c] = v;
        }
    }
    if count < wanted.len() {
        return Err(RowProblem::Narrow { count, width: wanted.len() });
    }
    Ok(())
}

/// The map as it was applied, in one line: what `info` prints.
fn understood(map: &ColumnMap, layout: &Layout) -> String {
    let unit = match map.time.unit {
        TimeUnit::Seconds => "s",
        TimeUnit::Milliseconds => "ms",
        TimeUnit::Microseconds => "us",
        TimeUnit::Nanoseconds => "ns",
    };
    let mut parts = vec![format!("time {} [{unit}]", layout.time + 1)];
    for (k, (name, j)) in map.joints.iter().enumerate() {
        let velocity = layout.velocity.as_ref().map_or(String::new(), |v| format!(" velocity {}", v[k] + 1));
        let effort = match (&j.current, layout.gain[k]) {
            (Some(_), _) if j.gain.is_none() => format!("current {} x --gains", layout.effort[k] + 1),
            (Some(_), g) => format!("current {} x {g}", layout.effort[k] + 1),
            (None, g) if g != 1.0 => format!("effort {} x {g}", layout.effort[k] + 1),
            (None, _) => format!("effort {}", layout.effort[k] + 1),
        };
        parts.push(format!("{name}: position {}{velocity} {effort}", layout.position[k] + 1));
    }
    parts.join("; ")
}

#[cfg(test)]
mod tests {
    use super::*;

    const MAP: &str = r#"
        time = { column = 1, unit = "ms" }
        [joints.a]
        position = 2
        velocity = 3
        effort = 4
        [joints.b]
        position = 5
        velocity = 6
        current = 7
        gain = 2.5
    "#;

    fn map(text: &str) -> ColumnMap {
        let map: ColumnMap = toml::from_str(text).unwrap();
        map.check().unwrap();
        map
    }

    fn table(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn rows_become_joint_states_in_joint_torque_with_the_map_s_time_unit() {
        let dir = tempfile::tempdir().unwrap();
        let path = table(dir.path(), "log.csv", "0,1,2,3,4,5,6,7\n\n2,1.5,2,3,4,5,6,8,99\n");
        let bag = read(&path, &map(MAP)).unwrap();
        assert_eq!(bag.joint_states.len(), 2);
        let m = &bag.joint_states[1];
        assert_eq!((m.sec, m.nanosec), (0, 2_000_000));
        assert_eq!(&*m.name, &["a".to_string(), "b".to_string()]);
        assert_eq!((m.position.as_slice(), m.velocity.as_slice()), (&[1.5, 4.0][..], &[2.0, 5.0][..]));
        assert_eq!(m.effort, [3.0, 15.0]);
        let record = &bag.metadata[META_TABLE];
        assert_eq!((record["rows"].as_str(), record["skipped_rows"].as_str()), ("2", "0"));
        assert_eq!(
            record["columns"],
            "time 1 [ms]; a: position 2 velocity 3 effort 4; b: position 5 velocity 6 current 7 x 2.5"
        );
    }

    #[test]
    fn lines_are_cut_into_pieces_at_line_ends_with_their_numbers() {
        let text = "t,ä\n1,2\n\n3,4\n5,6";
        let pieces = split_lines(text, 7);
        assert_eq!(pieces.iter().map(|p| p.0).collect::<String>(), text);
        assert!(pieces.iter().rev().skip(1).all(|p| p.0.ends_with('\n')), "{pieces:?}");
        for (piece, first) in &pieces {
            for (k, line) in piece.lines().enumerate() {
                let whole = text.lines().position(|l| std::ptr::eq(l, line) || l.as_ptr() == line.as_ptr());
                assert_eq!(Some(first + k - 7), whole, "{line:?} in {pieces:?}");
            }
        }
    }

    #[test]
    fn bad_rows_name_the_line_or_are_skipped_and_counted_when_asked() {
        let dir = tempfile::tempdir().unwrap();
        let text = "0,1,2,3,4,5,6,7\n1,1,2,3\n2,1,x,3,4,5,6,7\n1.5,1,2,3,4,5,6,7\n3,1,2,3,4,5,6,7\n";
        let path = table(dir.path(), "log.csv", text);
        let e = read(&path, &map(MAP)).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: line 2: 4 column(s)", path.display())) && e.contains("bad_rows"), "{e}");
        let skip = map(&format!("bad_rows = \"skip\"\n{MAP}"));
        let bag = read(&path, &skip).unwrap();
        assert_eq!(bag.joint_states.iter().map(|m| m.nanosec).collect::<Vec<_>>(), [0, 1_500_000, 3_000_000]);
        let record = &bag.metadata[META_TABLE];
        assert_eq!(record["skipped_rows"], "2");
        assert!(record["first_skipped"].starts_with("line 2: 4 column(s)"), "{}", record["first_skipped"]);
        // A row whose time goes backwards is named by its line too.
        let path = table(dir.path(), "back.csv", "0,1,2,3,4,5,6,7\n5,1,2,3,4,5,6,7\n4,1,2,3,4,5,6,7\n");
        let e = read(&path, &map(MAP)).unwrap_err().to_string();
        assert!(e.contains("line 3: the time goes backwards (4 after 5)"), "{e}");
        let path = table(dir.path(), "word.csv", "0,1,2,3,4,5,6,nan\n0,1,2,3,4,5,nan,7\n");
        let e = read(&path, &map(MAP)).unwrap_err().to_string();
        assert!(e.contains("line 2: column 7: NaN is not a finite number"), "{e}");
    }

    #[test]
    fn header_names_whitespace_and_a_current_without_gain() {
        let dir = tempfile::tempdir().unwrap();
        let named = r#"
            header = true
            skip_rows = 1
            time = { column = "stamp" }
            [joints.a]
            position = "q"
            current = "i"
        "#;
        let path = table(dir.path(), "log.txt", "# logger v2\nstamp  i  q\n0.5 3 1\n  0.75\t4 2  \n");
        let e = map(named).check_gains(false).unwrap_err().to_string();
        assert!(e.contains("joint 'a': its column is a current") && e.contains("--gains"), "{e}");
        assert_eq!(map(named).check_gains(true), Ok(()));
        let bag = read(&path, &map(named)).unwrap();
        let m = &bag.joint_states[1];
        assert_eq!((m.sec, m.nanosec, m.position[0], m.effort[0]), (0, 750_000_000, 2.0, 4.0));
        assert!(m.velocity.is_empty());
        assert!(bag.metadata[META_TABLE]["columns"].ends_with("a: position 3 current 2 x --gains"));
        let gained = map(&named.replace("current = \"i\"", "current = \"i\"\ngain = 3.0"));
        assert!(gained.check_gains(true).unwrap_err().to_string().contains("a gain in the column map and in --gains"));
        assert_eq!(read(&path, &gained).unwrap().joint_states[1].effort, [12.0]);
        let wrong = named.replace("\"q\"", "\"pos\"");
        let e = read(&path, &map(&wrong)).unwrap_err().to_string();
        assert!(e.contains("the header has no column 'pos'"), "{e}");
    }

    #[test]
    fn a_map_that_cannot_be_applied_is_refused_before_any_table_is_read() {
        let problem = |text: &str| {
            toml::from_str::<ColumnMap>(text)
                .map_err(|e| e.to_string())
                .and_then(|m| m.check().map_err(|e| e.to_string()))
        };
        let base = "time = { column = 1 }\n[joints.a]\nposition = 2\n";
        assert!(problem(&format!("{base}effort = 3\ncurrent = 4\n")).unwrap_err().contains("effort and current both"));
        assert!(problem(base).unwrap_err().contains("no effort or current column"));
        assert!(problem(&format!("{base}effort = 0\n")).unwrap_err().contains("columns count from 1"));
        assert!(problem(&format!("{base}effort = \"tau\"\n")).unwrap_err().contains("header = false"));
        assert!(
            problem(&format!("{base}effort = 3\n[joints.b]\nposition = 4\nvelocity = 5\neffort = 6\n"))
                .unwrap_err()
                .contains("velocity is given for some joints")
        );
        assert!(problem(&format!("{base}effort = 3\ngain = 0\n")).unwrap_err().contains("gain 0"));
        assert!(problem(&format!("{base}effort = 3\ntorque = 4\n")).unwrap_err().contains("unknown field"));
        assert!(problem("time = { column = 1 }\n[joints]\n").unwrap_err().contains("no [joints.NAME]"));
    }
}
