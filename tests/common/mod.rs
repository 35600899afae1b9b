//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::process::{Command, Output};

/// Runs the real `dynforge` binary to completion.
pub fn dynforge(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dynforge")).args(args).output().expect("dynforge runs")
}
