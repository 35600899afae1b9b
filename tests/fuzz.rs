//! Fuzzing the readers of everything a user or a crash can hand us — URDFs (also inside a log's
//! /robot_description), shards and bags, ledgers — with proptest: valid inputs cut, spliced and overwritten at random
//! places. Each reader must answer with a value or an error, never a panic or an abort. Bounded: a fixed number of
//! cases per reader (a few seconds in all), and the same cases on every run (proptest's fixed seed below).

use std::path::Path;

use dynforge_proto::generator::GeneratorConfig;
use dynforge_proto::job::Job;
use dynforge_proto::sim::SimConfig;
use dynforge_robot::generator::generate;
use dynforge_worker::job::Runner;
use dynforge_worker::output::Outcome;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

/// An edit of a byte string: where (a fraction of its length) and what.
#[derive(Debug, Clone)]
enum Edit {
    Truncate(f64),
    Overwrite(f64, Vec<u8>),
    Insert(f64, Vec<u8>),
    Delete(f64, usize),
    Duplicate(f64, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    let bytes = proptest::collection::vec(any::<u8>(), 1..16);
    prop_oneof![
        (0.0..1.0f64).prop_map(Edit::Truncate),
        (0.0..1.0f64, bytes.clone()).prop_map(|(a, b)| Edit::Overwrite(a, b)),
        (0.0..1.0f64, bytes).prop_map(|(a, b)| Edit::Insert(a, b)),
        (0.0..1.0f64, 1..4096usize).prop_map(|(a, n)| Edit::Delete(a, n)),
        (0.0..1.0f64, 1..4096usize).prop_map(|(a, n)| Edit::Duplicate(a, n)),
    ]
}

fn apply(mut v: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for e in edits {
        let at = |f: f64, len: usize| ((f * len as f64) as usize).min(len);
        match e {
            Edit::Truncate(f) => v.truncate(at(*f, v.len())),
            Edit::Overwrite(f, b) => {
                let i = at(*f, v.len());
                for (k, x) in b.iter().enumerate() {
                    if let Some(slot) = v.get_mut(i + k) {
                        *slot = *x;
                    }
                }
            }
            Edit::Insert(f, b) => {
                let i = at(*f, v.len());
                v.splice(i..i, b.iter().copied());
            }
            Edit::Delete(f, n) => {
                let i = at(*f, v.len());
                v.drain(i..(i + n).min(v.len()));
            }
            Edit::Duplicate(f, n) => {
                let i = at(*f, v.len());
                let piece: Vec<u8> = v[i..(i + n).min(v.len())].to_vec();
                v.splice(i..i, piece);
            }
        }
    }
    v
}

/// Runs `check` on `cases` edited copies of `valid`, with a fixed seed.
fn fuzz(valid: &[u8], cases: u32, check: impl Fn(&[u8])) {
    let config = Config { cases, failure_persistence: None, ..Config::default() };
    let rng = TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]);
    let mut runner = TestRunner::new_with_rng(config, rng);
    let edits = proptest::collection::vec(edit(), 1..4);
    runner
        .run(&edits, |e| {
            check(&apply(valid.to_vec(), &e));
            Ok(())
        })
        .unwrap();
}

#[test]
fn the_urdf_reader_never_panics() {
    let urdf = generate(&GeneratorConfig::default(), 1, 0).unwrap().urdf();
    fuzz(urdf.as_bytes(), 2000, |b| {
        let _ = dynforge_robot::urdf::parse(&String::from_utf8_lossy(b), "fuzz.urdf");
    });
}

#[test]
fn writing_into_a_users_urdf_never_panics() {
    let robot = generate(&GeneratorConfig::default(), 1, 0).unwrap();
    let other = generate(&GeneratorConfig::default(), 1, 1).unwrap().model;
    // A fixed tool, so that the welded-inertia path is reached too.
    let tool = "<joint name=\"t\" type=\"fixed\"><parent link=\"link_6\"/><child link=\"tool\"/></joint><link \
                name=\"tool\"><inertial><mass value=\"0.5\"/><inertia ixx=\"1e-3\" ixy=\"0\" ixz=\"0\" iyy=\"1e-3\" \
                iyz=\"0\" izz=\"1e-3\"/></inertial></link></robot>";
    let urdf = robot.urdf().replace("</robot>", tool);
    fuzz(urdf.as_bytes(), 1000, |b| {
        let _ = dynforge_robot::urdf::patch(&String::from_utf8_lossy(b), "fuzz.urdf", &other);
    });
}

#[test]
fn the_shard_and_bag_readers_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let job = Job { seed: 1, robot: 0, trajectory: 0 };
    let Outcome::Written { path, .. } =
        Runner::new(GeneratorConfig::default(), SimConfig::default()).run(&job, dir.path()).unwrap()
    else {
        panic!("the job is kept")
    };
    let shard = std::fs::read(&path).unwrap();
    // Edits almost always break the data-section CRC, which is checked first; with the CRC cleared (0: absent, as
    // some writers leave it) they reach the MCAP records, the CDR messages and the joint matching.
    let mut without_crc = shard.clone();
    let footer = shard.len() - 8 - 29;
    let summary = u64::from_le_bytes(shard[footer + 9..footer + 17].try_into().unwrap()) as usize;
    let data_end = if summary == 0 { footer } else { summary } - 13;
    assert_eq!(shard[data_end], 0x0F, "the DataEnd record");
    without_crc[data_end + 9..data_end + 13].fill(0);
    let file = dir.path().join("fuzzed.mcap");
    fuzz(&shard, 100, |b| {
        let _ = dynforge_shard::read_bytes(b, Path::new("fuzzed.mcap"));
    });
    fuzz(&without_crc, 300, |b| {
        // The MCAP layer, then the whole read (robot description, joint matching, resampling) from a file.
        let _ = dynforge_shard::read_bytes(b, Path::new("fuzzed.mcap"));
        std::fs::write(&file, b).unwrap();
        if let Err(e) = dynforge_recording::read(&file, None) {
            assert!(e.to_string().contains("fuzzed.mcap"), "an error that does not name the file: {e}");
        }
    });
}

#[test]
fn the_ledger_parser_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ledger.tsv");
    let mut valid = String::new();
    {
        let (mut ledger, _) = dynforge_proto::ledger::Ledger::open(&path).unwrap();
        use dynforge_proto::ledger::{Entry, Status};
        let statuses = [
            Status::Done { samples: 6000, shard_hash: 0x1234_5678_9abc_def0 },
            Status::Discarded { reason: "timeout".into() },
            Status::Failed { message: "worker error: No space left on device (os error 28)".into() },
        ];
        for (k, status) in statuses.into_iter().enumerate() {
            ledger.append(&Entry { job_id: k as u64, robot: 0, trajectory: k as u32, status }).unwrap();
        }
        valid.push_str(&std::fs::read_to_string(&path).unwrap());
    }
    fuzz(valid.as_bytes(), 2000, |b| {
        std::fs::write(&path, b).unwrap();
        if let Err(e) = dynforge_proto::ledger::read(&path) {
            assert!(e.to_string().contains("ledger.tsv"), "an error that does not name the file: {e}");
        }
    });
}
