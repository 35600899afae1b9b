//! rosbag2's sqlite3 storage: what `ros2 bag record` writes up to ROS 2 Humble (`NAME/NAME_0.db3` beside
//! `metadata.yaml`). Each file is an SQLite database whose `topics` table names each topic's type and serialisation
//! and whose `messages` table holds the serialised messages, in the order they were recorded; the messages are the
//! same CDR an MCAP bag holds, so both storages of one recording give the same [`Bag`].

use std::path::Path;

use dynforge_proto::shard::{self as contract, JointState, JointStateDecoder};
use dynforge_shard::{Bag, decode_message};
use rusqlite::{Connection, OpenFlags};

use crate::error::ReadError;

/// The extension rosbag2 gives its sqlite3 files.
pub const EXTENSION: &str = "db3";

/// The `/joint_states` and `/robot_description` of the sqlite3 files `paths` (one recording, in recording order)
/// as one bag. A bag's metadata lives in `metadata.yaml`, not in its files: the bag has none, and no CRC.
pub fn read_joined(paths: &[impl AsRef<Path>]) -> Result<Bag, ReadError> {
    let mut bag = Bag::default();
    for path in paths {
        read_into(path.as_ref(), &mut bag)?;
    }
    Ok(bag)
}

/// The messages of the file `path` added to `bag`.
fn read_into(path: &Path, bag: &mut Bag) -> Result<(), ReadError> {
    let content = |problem: String| ReadError::Content { file: path.display().to_string(), problem };
    let sql = |e: rusqlite::Error| content(format!("not a readable rosbag2 sqlite3 file: {e}"));
    // Read-only and without a lock: a bag is read while nothing writes it, and it may sit on a read-only mount.
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX | OpenFlags::SQLITE_OPEN_URI;
    if !path.is_file() {
        return Err(content("no such file".into()));
    }
    let uri = format!("file:{}?immutable=1", uri_path(path));
    let db = Connection::open_with_flags(uri, flags).map_err(sql)?;
    let mut topics = db.prepare("SELECT id, name, type, serialization_format FROM topics").map_err(sql)?;
    let topics: Vec<(i64, String, String, String)> = topics
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)))
        .map_err(sql)?
        .collect::<Result<_, _>>()
        .map_err(sql)?;
    let wanted: Vec<&(i64, String, String, String)> = topics
        .iter()
        .filter(|(_, topic, schema, encoding)| dynforge_shard::reads_topic(topic, schema, encoding))
        .collect();
    if wanted.is_empty() {
        return Ok(());
    }
    let ids: Vec<String> = wanted.iter().map(|t| t.0.to_string()).collect();
    // In the order recorded (the row id: rosbag2 inserts each message as it arrives), as an MCAP bag's file order.
    let query = format!("SELECT topic_id, data FROM messages WHERE topic_id IN ({}) ORDER BY id", ids.join(","));
    let mut statement = db.prepare(&query).map_err(sql)?;
    let mut rows = statement.query([]).map_err(sql)?;
    let mut decoder = JointStateDecoder::default();
    let mut row_number = 0u64;
    while let Some(row) = rows.next().map_err(sql)? {
        row_number += 1;
        let id: i64 = row.get(0).map_err(sql)?;
        let data = row.get_ref(1).map_err(sql)?.as_blob().map_err(|e| sql(e.into()))?;
        let (_, topic, schema, encoding) = wanted.iter().find(|t| t.0 == id).expect("selected by these ids");
        match decode_message(topic, schema, encoding, data, &mut decoder) {
            Ok(Some(message)) => bag.push(message),
            Ok(None) => {}
            Err(e) => return Err(content(format!("message {row_number} on {topic}: {e}"))),
        }
    }
    Ok(())
}

/// Writes `states` (and `description` as `/robot_description` first, if given) to a new file `path` laid out as
/// rosbag2's sqlite3 storage writes it (its `schema`, `metadata`, `topics` and `messages` tables; one transaction): a
/// Humble bag for the tests and benchmarks of the readers, which do not need ROS to make one.
pub fn write(path: &Path, description: Option<&str>, states: &[JointState]) -> Result<(), ReadError> {
    let content = |problem: String| ReadError::Content { file: path.display().to_string(), problem };
    let sql = |e: rusqlite::Error| content(e.to_string());
    let mut db = Connection::open(path).map_err(sql)?;
    let tx = db.transaction().map_err(sql)?;
    tx.execute_batch(SCHEMA).map_err(sql)?;
    {
        let mut insert =
            tx.prepare("INSERT INTO messages (topic_id, timestamp, data) VALUES (?1, ?2, ?3)").map_err(sql)?;
        if let Some(text) = description {
            let at = states.first().map_or(0, JointState::stamp_ns);
            insert.execute((2, at, contract::encode_string(text))).map_err(sql)?;
        }
        for m in states {
            insert.execute((1, m.stamp_ns(), contract::encode_joint_state(m))).map_err(sql)?;
        }
    }
    tx.commit().map_err(sql)
}

/// rosbag2's sqlite3 schema (Humble), with the two topics dynforge reads.
const SCHEMA: &str = "
    CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
    INSERT INTO schema VALUES (3, 'humble');
    CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL, metadata TEXT NOT NULL);
    CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
        serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
    CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, timestamp INTEGER NOT NULL,
        data BLOB NOT NULL);
    CREATE INDEX timestamp_idx ON messages (timestamp ASC);
    INSERT INTO topics VALUES (1, '/joint_states', 'sensor_msgs/msg/JointState', 'cdr', '');
    INSERT INTO topics VALUES (2, '/robot_description', 'std_msgs/msg/String', 'cdr', '');";

/// `path` as the path of an SQLite URI: every byte but the unreserved ones and `/` percent-encoded.
fn uri_path(path: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let mut out = String::new();
    for &b in path.as_os_str().as_bytes() {
        match b {
            b'a'..=b'z' | b'A'..=b'Z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' | b'/' => out.push(b as char),
            _ => out.push_str(&format!("%{b:02X}")),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bag as [`write`] writes it, with a message of another topic among its joint states.
    fn bag(path: &Path, description: &str, states: &[JointState]) {
        write(path, Some(description), states).unwrap();
        let db = Connection::open(path).unwrap();
        db.execute_batch(
            "INSERT INTO topics VALUES (3, '/tf', 'tf2_msgs/msg/TFMessage', 'cdr', '');
             INSERT INTO messages (topic_id, timestamp, data) VALUES (3, 9, x'010203');",
        )
        .unwrap();
    }

    fn state(k: u32) -> JointState {
        JointState {
            sec: 1,
            nanosec: k,
            name: vec!["j0".to_string()].into(),
            position: vec![k as f64],
            velocity: vec![],
            effort: vec![-(k as f64)],
            ..JointState::default()
        }
    }

    #[test]
    fn joint_states_and_the_description_are_read_in_recorded_order_and_other_topics_left() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b_0.db3");
        bag(&path, "<robot name='r'/>", &[state(2), state(1)]);
        let read = read_joined(&[&path]).unwrap();
        assert_eq!(read.robot_description.as_deref(), Some("<robot name='r'/>"));
        assert_eq!(read.joint_states, [state(2), state(1)]);
        assert!(!read.crc_checked && read.metadata.is_empty());
    }

    #[test]
    fn a_damaged_message_or_a_file_that_is_no_bag_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("torn?#%.db3");
        bag(&path, "<robot name='r'/>", &[state(0), state(1)]);
        let db = Connection::open(&path).unwrap();
        db.execute("UPDATE messages SET data = substr(data, 1, 30) WHERE id = 3", []).unwrap();
        let e = read_joined(&[&path]).unwrap_err().to_string();
        assert!(e.starts_with(&path.display().to_string()) && e.contains("message 3 on /joint_states"), "{e}");
        let text = dir.path().join("text.db3");
        std::fs::write(&text, "not a database").unwrap();
        let e = read_joined(&[&text]).unwrap_err().to_string();
        assert!(e.starts_with(&text.display().to_string()) && e.contains("not a readable rosbag2 sqlite3 file"), "{e}");
        let e = read_joined(&[dir.path().join("absent.db3")]).unwrap_err().to_string();
        assert!(e.contains("absent.db3: no such file"), "{e}");
    }
}
