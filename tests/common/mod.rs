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
