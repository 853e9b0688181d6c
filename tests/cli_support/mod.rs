//! Running the `fsrl` binary from a test: its output, or an assertion that it succeeded or
//! failed. Shared by tests/cli_pictures.rs and tests/models.rs.

use std::path::Path;
use std::process::{Command, Output};

pub fn fsrl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(args)
        .output()
        .unwrap()
}

/// Runs `fsrl args`, asserts it succeeded and returns its stdout.
pub fn ok(args: &[&str]) -> String {
    let o = fsrl(args);
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "fsrl {args:?} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
}

/// Runs `fsrl args`, asserts it failed and returns its stderr.
pub fn fails(args: &[&str]) -> String {
    let o = fsrl(args);
    assert!(!o.status.success(), "fsrl {args:?} should fail");
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
