//! What the reference-replay tests (`orca_ref`, `sf_ref`) share: finding their scene files.

use std::path::{Path, PathBuf};

/// The reference scenes: every `*.csv` below the directory `env_var` names when it is set, else
/// below each of `defaults` (under the repository's `testdata/`), subdirectories included,
/// sorted; with what was searched, for messages. Finding none fails: nothing would be compared.
pub fn reference_csvs(env_var: &str, defaults: &[&str], what: &str) -> (PathBuf, Vec<PathBuf>) {
    let root = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../testdata"));
    let (label, dirs) = match std::env::var_os(env_var) {
        Some(dir) => (PathBuf::from(&dir), vec![PathBuf::from(dir)]),
        None => (
            root.clone(),
            defaults.iter().map(|d| root.join(d)).collect(),
        ),
    };
    let mut files = Vec::new();
    for dir in &dirs {
        csv_files(dir, what, &mut files);
    }
    files.sort();
    assert!(
        !files.is_empty(),
        "no {what} reference scenes (*.csv) found in {}: nothing was compared",
        label.display()
    );
    (label, files)
}

fn csv_files(dir: &Path, what: &str, out: &mut Vec<PathBuf>) {
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| {
        panic!(
            "cannot read {what} reference directory {}: {e}",
            dir.display()
        )
    });
    for entry in entries {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            csv_files(&path, what, out);
        } else if path.extension().is_some_and(|e| e == "csv") {
            out.push(path);
        }
    }
}
