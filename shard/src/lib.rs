//! MCAP shards: writing dynforge's (atomically, byte-reproducibly) and reading them back, together with any
//! ROS 2 bag that carries `sensor_msgs/msg/JointState` on `/joint_states` (the layout is in
//! [`dynforge_proto::shard`]).

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use dynforge_proto::shard::{self as contract, JointState};

/// Metadata records: record name -> key -> value.
pub type Metadata = BTreeMap<String, BTreeMap<String, String>>;

/// What can go wrong with a shard; always names the file.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not a readable MCAP file: {message}")]
    Mcap { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Content { path: PathBuf, message: String },
}

/// Zstd chunks of about a quarter second of 1 kHz joint states.
const CHUNK_SIZE: u64 = 64 * 1024;

/// One shard's content to write.
pub struct ShardContent<'a> {
    pub urdf: &'a str,
    /// The joint-state messages, in time order.
    pub joint_states: &'a [JointState],
    pub metadata: &'a Metadata,
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> ShardError + '_ {
    move |source| ShardError::Io { path: path.to_path_buf(), source }
}

/// An MCAP error as ours. Its I/O variant stays an I/O error with the OS's own words ("No space left on device"):
/// the MCAP crate's text for it ("I/O error from writing, or reading a compression stream") names no cause.
fn mcap_err(path: &Path) -> impl Fn(mcap::McapError) -> ShardError + '_ {
    move |e| match e {
        mcap::McapError::Io(source) => ShardError::Io { path: path.to_path_buf(), source },
        e => ShardError::Mcap { path: path.to_path_buf(), message: e.to_string() },
    }
}

/// Writes a shard to `path` by the temporary-file rule ([`dynforge_proto::run_dir`]); the same content always gives
/// the same bytes, and a data-section CRC that is not 0 (see [`read_bytes`]: readers refuse a dataset shard without
/// one). Returns the file's [`content_hash`].
pub fn write(path: &Path, content: &ShardContent<'_>) -> Result<u64, ShardError> {
    if path.file_name().is_none() {
        return Err(ShardError::Content { path: path.into(), message: "not a file path".into() });
    }
    dynforge_proto::run_dir::replace_atomically(
        path,
        |tmp| {
            let mut metadata = content.metadata.clone();
            for nonce in 1u32.. {
                write_file(tmp, &ShardContent { metadata: &metadata, ..*content })?;
                let bytes = std::fs::read(tmp).map_err(io_err(tmp))?;
                // MCAP's 0 means "no CRC". One CRC in 2^32 is 0: a record that changes the bytes, deterministically.
                if data_section_crc(&bytes) != Some(0) {
                    return Ok(content_hash(&bytes));
                }
                metadata.insert(NONZERO_CRC.into(), [("nonce".to_string(), nonce.to_string())].into());
            }
            unreachable!("a CRC other than 0 within 2^32 nonces")
        },
        |p, e| io_err(p)(e),
    )
}

type Ros2Writer = mcap::Writer<BufWriter<std::fs::File>>;

/// An MCAP writer as rosbag2 writes them (its profile, zstd chunks), with fixed library string, chunk size and no
/// compression threads, so the same content gives the same bytes.
fn ros2_writer(file: std::fs::File, path: &Path) -> Result<Ros2Writer, ShardError> {
    mcap::WriteOptions::new()
        .profile(contract::PROFILE)
        .library(contract::LIBRARY)
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(CHUNK_SIZE))
        .compression_threads(0)
        .create(BufWriter::new(file))
        .map_err(mcap_err(path))
}

/// A channel on `topic` of the `ros2msg` schema `name` with `definition`; its id.
fn channel(w: &mut Ros2Writer, path: &Path, name: &str, definition: &str, topic: &str) -> Result<u16, ShardError> {
    let me = mcap_err(path);
    let schema = w.add_schema(name, contract::SCHEMA_ENCODING, definition.as_bytes()).map_err(&me)?;
    // rosbag2 parses this key; an empty value means "no QoS profiles recorded".
    let meta = BTreeMap::from([("offered_qos_profiles".to_string(), String::new())]);
    w.add_channel(schema, topic, contract::MESSAGE_ENCODING, &meta).map_err(&me)
}

/// The metadata record a shard whose data-section CRC would be 0 gets, to change it.
const NONZERO_CRC: &str = "dynforge_nonzero_crc";

fn write_file(path: &Path, content: &ShardContent<'_>) -> Result<(), ShardError> {
    let file = dynforge_proto::run_dir::create_temporary(path).map_err(io_err(path))?;
    let me = mcap_err(path);
    let mut w = ros2_writer(file, path)?;
    let description =
        channel(&mut w, path, contract::SCHEMA_STRING, contract::STRING_DEFINITION, contract::TOPIC_ROBOT_DESCRIPTION)?;
    let joints = channel(
        &mut w,
        path,
        contract::SCHEMA_JOINT_STATE,
        contract::JOINT_STATE_DEFINITION,
        contract::TOPIC_JOINT_STATES,
    )?;
    let t0 = content.joint_states.first().map_or(0, |m| m.stamp_ns().max(0) as u64);
    let header = |channel_id, sequence, time| mcap::records::MessageHeader {
        channel_id,
        sequence,
        log_time: time,
        publish_time: time,
    };
    w.write_to_known_channel(&header(description, 0, t0), &contract::encode_string(content.urdf)).map_err(&me)?;
    for (k, m) in content.joint_states.iter().enumerate() {
        let t = m.stamp_ns().max(0) as u64;
        w.write_to_known_channel(&header(joints, k as u32, t), &contract::encode_joint_state(m)).map_err(&me)?;
    }
    for (name, map) in content.metadata {
        w.write_metadata(&mcap::records::Metadata { name: name.clone(), metadata: map.clone() }).map_err(&me)?;
    }
    w.finish().map_err(&me)?;
    let file = w.into_inner().into_inner().map_err(|e| io_err(path)(e.into_error()))?;
    file.sync_all().map_err(io_err(path))
}

/// Writes one `trajectory_msgs/msg/JointTrajectory` of the joints `names` on
/// [`contract::TOPIC_JOINT_TRAJECTORY`] to a new MCAP file at `path` (written whole, then renamed): a trajectory as
/// `ros2 bag play` hands it to a joint_trajectory_controller.
pub fn write_joint_trajectory(
    path: &Path,
    names: &[String],
    points: &[contract::TrajectoryPoint],
) -> Result<(), ShardError> {
    dynforge_proto::run_dir::replace_atomically(
        path,
        |tmp| {
            let file = dynforge_proto::run_dir::create_temporary(tmp).map_err(io_err(tmp))?;
            let me = mcap_err(tmp);
            let mut w = ros2_writer(file, tmp)?;
            let channel = channel(
                &mut w,
                tmp,
                contract::SCHEMA_JOINT_TRAJECTORY,
                contract::JOINT_TRAJECTORY_DEFINITION,
                contract::TOPIC_JOINT_TRAJECTORY,
            )?;
            let header =
                mcap::records::MessageHeader { channel_id: channel, sequence: 0, log_time: 0, publish_time: 0 };
            w.write_to_known_channel(&header, &contract::encode_joint_trajectory(names, points)).map_err(&me)?;
            w.finish().map_err(&me)?;
            let file = w.into_inner().into_inner().map_err(|e| io_err(tmp)(e.into_error()))?;
            file.sync_all().map_err(io_err(tmp))
        },
        |p, e| io_err(p)(e),
    )
}

use dynforge_proto::content_hash;

/// A decoded bag or shard.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Bag {
    /// The last `/robot_description` message, if any.
    pub robot_description: Option<String>,
    /// Every `/joint_states` message, in file order.
    pub joint_states: Vec<JointState>,
    pub metadata: Metadata,
    /// Whether the file carried a data-section CRC, which matched (MCAP allows none: a bag without one is read, but
    /// nothing vouches for its records outside chunks, such as a shard's labels).
    pub crc_checked: bool,
}

/// Reads a shard or a ROS 2 bag. Truncated or corrupt files are errors naming the file, never panics.
pub fn read(path: &Path) -> Result<Bag, ShardError> {
    read_joined(&[path])
}

/// Reads the files of one log as one bag, as a recorder splits it (a rosbag2 directory's files, in recording order):
/// the messages of all in order, the last `/robot_description` of any, the metadata of all (a later file's name
/// over an earlier's), CRC-checked if every file was. Each file's bytes are dropped once it is decoded, and every
/// message is moved once, into a vector sized once: an hour of log is millions of messages, and each copy of them
/// faults in and zeroes hundreds of megabytes more.
pub fn read_joined(paths: &[impl AsRef<Path>]) -> Result<Bag, ShardError> {
    let mut parts = Vec::with_capacity(paths.len());
    for path in paths {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(io_err(path))?;
        parts.push(read_parts(&bytes, path)?);
    }
    Ok(assemble(parts))
}

/// The CRC the writer put in the file's DataEnd record (MCAP's `data_section_crc`: every byte from the leading magic
/// up to that record; 0 means none was computed), if the file ends in the records that carry it. Any offset that does
/// not fit is a malformed file: `None`, left to the MCAP reader to report.
fn data_section_crc(bytes: &[u8]) -> Option<u32> {
    data_end(bytes).map(|at| u32::from_le_bytes(bytes[at + 9..at + 13].try_into().expect("4 bytes")))
}

/// Where the DataEnd record starts.
fn data_end(bytes: &[u8]) -> Option<usize> {
    const MAGIC: usize = 8;
    const FOOTER: usize = 1 + 8 + 8 + 8 + 4;
    const DATA_END: usize = 1 + 8 + 4;
    let u64_at = |at: usize| bytes.get(at..at + 8).map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")));
    let footer = bytes.len().checked_sub(MAGIC + FOOTER)?;
    if bytes.get(footer) != Some(&0x02) {
        return None;
    }
    let summary_start = u64_at(footer + 9).and_then(|v| usize::try_from(v).ok()).unwrap_or(0);
    let end = if summary_start == 0 { footer } else { summary_start };
    let data_end = end.checked_sub(DATA_END).filter(|&d| d + DATA_END <= footer)?;
    (bytes.get(data_end) == Some(&0x0F) && u64_at(data_end + 1) == Some(4)).then_some(data_end)
}

/// Checks the data-section CRC when the file has one; whether it had. The reader checks each chunk's CRC but not this
/// one, and the records outside chunks (our labels and job, the robot description) are covered by nothing else:
/// without this check a label edited in place would be read, and trained on, without a word.
fn check_data_section(bytes: &[u8]) -> Result<bool, CrcMismatch> {
    let Some(at) = data_end(bytes) else { return Ok(false) };
    let recorded = u32::from_le_bytes(bytes[at + 9..at + 13].try_into().expect("4 bytes"));
    if recorded == 0 {
        return Ok(false);
    }
    let actual = crc32fast::hash(&bytes[..at]);
    if recorded != actual {
        return Err(CrcMismatch { recorded, actual });
    }
    Ok(true)
}

/// A file whose data section does not have the CRC it records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "the data section's CRC is {actual:08x}, the file records {recorded:08x}: it was changed or damaged after it \
     was written"
)]
struct CrcMismatch {
    recorded: u32,
    actual: u32,
}

/// Like [`read`], from memory; `path` only labels errors.
pub fn read_bytes(bytes: &[u8], path: &Path) -> Result<Bag, ShardError> {
    Ok(assemble(vec![read_parts(bytes, path)?]))
}

/// A file decoded, its messages still chunk by chunk.
struct Parts {
    decoded: Vec<Vec<Message>>,
    metadata: Metadata,
    crc_checked: bool,
}

/// The bag of the files `parts`, in order (see [`read_joined`]).
fn assemble(parts: Vec<Parts>) -> Bag {
    let mut bag = Bag { crc_checked: !parts.is_empty() && parts.iter().all(|p| p.crc_checked), ..Bag::default() };
    bag.joint_states.reserve_exact(parts.iter().flat_map(|p| &p.decoded).map(Vec::len).sum());
    for part in parts {
        part.decoded.into_iter().flatten().for_each(|m| bag.push(m));
        bag.metadata.extend(part.metadata);
    }
    bag
}

impl Bag {
    /// Adds a message read after the ones the bag holds.
    pub fn push(&mut self, message: Message) {
        match message {
            Message::JointState(m) => self.joint_states.push(m),
            Message::Description(text) => self.robot_description = Some(text),
        }
    }
}

/// The messages and metadata of the file `bytes` (`path` labels errors).
fn read_parts(bytes: &[u8], path: &Path) -> Result<Parts, ShardError> {
    let me = mcap_err(path);
    let content = |message: String| ShardError::Content { path: path.to_path_buf(), message };
    if bytes.starts_with(mcap::MAGIC) && !bytes.ends_with(mcap::MAGIC) {
        return Err(content(format!(
            "an MCAP file cut short ({} bytes, no closing magic): a recording killed before it closed the file, or a \
             partial copy. `mcap recover` (the MCAP command-line tool) rewrites the messages it holds as a whole file",
            bytes.len()
        )));
    }
    let crc_checked = check_data_section(bytes).map_err(|e| content(e.to_string()))?;
    let summary = mcap::read::Summary::read(bytes).map_err(&me)?;
    let decoded = match summary.as_ref().filter(|s| !s.chunk_indexes.is_empty() && !top_level_messages(bytes)) {
        Some(summary) => read_chunks(bytes, summary, path)?,
        None => {
            let options = mcap::read::Options::ValidateChunkCrcs.into();
            let stream = mcap::MessageStream::new_with_options(bytes, options).map_err(&me)?;
            let (mut out, mut decoder) = (Vec::new(), contract::JointStateDecoder::default());
            for message in stream {
                out.extend(decode(&message.map_err(&me)?, path, &mut decoder)?);
            }
            vec![out]
        }
    };
    let mut metadata = Metadata::default();
    match summary {
        Some(summary) => {
            for index in &summary.metadata_indexes {
                let m = mcap::read::metadata(bytes, index).map_err(&me)?;
                metadata.insert(m.name, m.metadata);
            }
        }
        None => {
            for record in mcap::read::LinearReader::new(bytes).map_err(&me)? {
                if let mcap::records::Record::Metadata(m) = record.map_err(&me)? {
                    metadata.insert(m.name, m.metadata);
                }
            }
        }
    }
    Ok(Parts { decoded, metadata, crc_checked })
}

/// A message of a topic dynforge reads.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    JointState(JointState),
    Description(String),
}

/// `message` decoded, if it is on a topic dynforge reads.
fn decode(
    message: &mcap::Message,
    path: &Path,
    decoder: &mut contract::JointStateDecoder,
) -> Result<Option<Message>, ShardError> {
    let channel = &message.channel;
    let schema = channel.schema.as_ref().map_or("", |s| s.name.as_str());
    decode_message(&channel.topic, schema, &channel.message_encoding, &message.data, decoder).map_err(|e| {
        ShardError::Content {
            path: path.to_path_buf(),
            message: format!("message {} on {}: {e}", message.sequence, channel.topic),
        }
    })
}

/// Whether messages on `topic` of the type `schema` serialised as `encoding` are ones dynforge reads.
pub fn reads_topic(topic: &str, schema: &str, encoding: &str) -> bool {
    encoding == contract::MESSAGE_ENCODING
        && matches!(
            (topic, schema),
            (contract::TOPIC_JOINT_STATES, contract::SCHEMA_JOINT_STATE)
                | (contract::TOPIC_ROBOT_DESCRIPTION, contract::SCHEMA_STRING)
        )
}

/// The payload `data` of a message on `topic` of the type `schema` (`sensor_msgs/msg/JointState`) serialised as
/// `encoding` (`cdr`) decoded, if it is one dynforge reads (`/joint_states`, `/robot_description`): what every
/// storage of a ROS 2 bag (MCAP, sqlite3) holds alike.
pub fn decode_message(
    topic: &str,
    schema: &str,
    encoding: &str,
    data: &[u8],
    decoder: &mut contract::JointStateDecoder,
) -> Result<Option<Message>, contract::CdrError> {
    if !reads_topic(topic, schema, encoding) {
        return Ok(None);
    }
    Ok(match (topic, schema) {
        (contract::TOPIC_JOINT_STATES, contract::SCHEMA_JOINT_STATE) => {
            Some(Message::JointState(decoder.decode(data)?))
        }
        (contract::TOPIC_ROBOT_DESCRIPTION, contract::SCHEMA_STRING) => {
            Some(Message::Description(contract::decode_string(data)?))
        }
        _ => None,
    })
}

/// Whether the file has messages outside its chunks (MCAP allows it; then only the linear reader sees them all), or
/// records the linear reader cannot parse (it then reports them).
fn top_level_messages(bytes: &[u8]) -> bool {
    let Ok(records) = mcap::read::LinearReader::new(bytes) else { return true };
    records.into_iter().any(|r| matches!(r, Ok(mcap::records::Record::Message { .. }) | Err(_)))
}

/// The messages of every chunk of an indexed file (channels from its summary), chunk by chunk in file order, the
/// chunks decompressed and decoded side by side: most of the time spent reading a long log.
fn read_chunks(bytes: &[u8], summary: &mcap::read::Summary, path: &Path) -> Result<Vec<Vec<Message>>, ShardError> {
    let me = mcap_err(path);
    let mut indexes = summary.chunk_indexes.clone();
    indexes.sort_by_key(|i| i.chunk_start_offset);
    let parts = dynforge_proto::parallel::map_in_order(&indexes, |index| -> Result<Vec<Message>, ShardError> {
        let (mut out, mut decoder) = (Vec::new(), contract::JointStateDecoder::default());
        for message in summary.stream_chunk(bytes, index).map_err(&me)? {
            out.extend(decode(&message.map_err(&me)?, path, &mut decoder)?);
        }
        Ok(out)
    });
    parts.into_iter().collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_label_edited_in_place_is_refused_by_the_data_section_crc() {
        use super::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let states: Vec<JointState> = (0..50)
            .map(|k| JointState {
                sec: 0,
                nanosec: k * 1_000_000,
                frame_id: String::new(),
                name: vec!["j0".into()].into(),
                position: vec![k as f64],
                velocity: vec![1.0],
                effort: vec![0.5],
            })
            .collect();
        let metadata: Metadata = [("labels".to_string(), [("mass_l2".to_string(), "10.78".to_string())].into())].into();
        write(&path, &ShardContent { urdf: "<robot name='r'/>", joint_states: &states, metadata: &metadata }).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let bag = read_bytes(&bytes, &path).unwrap();
        assert_eq!(bag.metadata["labels"]["mass_l2"], "10.78");

        // The same length, so every offset still holds and only the CRC can tell.
        let at = bytes.windows(5).position(|w| w == b"10.78").expect("the label's text is in the file");
        let mut edited = bytes.clone();
        edited[at] = b'9';
        let e = read_bytes(&edited, &path).unwrap_err().to_string();
        assert!(e.contains("s.mcap") && e.contains("changed or damaged after it was written"), "{e}");
    }
}
