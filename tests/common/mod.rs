//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::process::{Command, Output};

/// Runs the real `dynforge` binary to completion.
pub fn dynforge(args: &[&str]) -> Output {
    dynforge_with_env(args, &[])
}

/// Runs the CLI with extra environment variables (e.g. fault injection).
#[allow(dead_code)]
pub fn dynforge_with_env(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dynforge")).args(args).envs(env.iter().copied()).output().expect("dynforge runs")
}

/// Process ids whose parent is `pid`.
pub fn children_of(pid: u32) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|p| {
            std::fs::read_to_string(format!("/proc/{p}/stat"))
                .ok()
                .and_then(|s| s.rsplit_once(')').map(|(_, rest)| rest.split_whitespace().nth(1).map(str::to_string)))
                .flatten()
                .is_some_and(|ppid| ppid == pid.to_string())
        })
        .collect()
}

/// File name -> content hash of every shard in a run directory.
pub fn shard_hashes(dir: &std::path::Path) -> std::collections::BTreeMap<String, u64> {
    std::fs::read_dir(dir.join("shards"))
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().to_string(),
                dynforge_proto::content_hash(&std::fs::read(e.path()).unwrap()),
            )
        })
        .collect()
}
