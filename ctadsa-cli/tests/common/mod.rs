//! Helpers shared by the CLI tests: the binary, scratch folders, a small synthetic case.
#![allow(dead_code)] // each test file uses a subset

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "../../../tests/scratch/mod.rs"]
mod scratch;
use scratch::scratch;

/// The `ctadsa` binary built for these tests.
pub const BIN: &str = env!("CARGO_BIN_EXE_ctadsa");

/// A scratch path for one test ([`scratch`]: removed by the next run of the test binary).
pub fn tmp(name: &str) -> PathBuf {
    scratch(&format!("cli-{name}"))
}

/// A small procedural case (16 terminals, 96² px views binned by 2) from `seed` in `dir`.
pub fn small_case_from(dir: &Path, seed: u64) {
    let synth = Command::new(BIN)
        .args(["synth", "--out", dir.to_str().unwrap(), "--terminals", "16", "--detector-px", "96"])
        .args(["--binning", "2", "--voxel-mm", "0.6", "--seed", &seed.to_string()])
        .output()
        .unwrap();
    assert!(synth.status.success(), "{}", String::from_utf8_lossy(&synth.stderr));
}

/// [`small_case_from`] with the default seed.
pub fn small_case(dir: &Path) {
    small_case_from(dir, 1)
}
