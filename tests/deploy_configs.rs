//! Every configuration file in `deploy/` parses and validates, and a broken one is refused.

use std::path::Path;
use std::process::Command;

#[test]
fn every_deploy_config_is_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 4,
        "expected the deploy configs, found {files:?}"
    );
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("check-config")
        .args(&files)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(
        out.lines().filter(|l| l.starts_with("ok: ")).count(),
        files.len(),
        "{out}"
    );
}

#[test]
fn a_broken_config_is_refused_with_every_problem() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("bad.toml");
    std::fs::write(
        &p,
        "[run]\nid = \"a/b\"\nmethod = \"ppo\"\n[learner]\nin_flight_per_actor = 0\n",
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("check-config")
        .arg(&p)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    for needle in ["run.id", "unknown method `ppo`", "in_flight_per_actor"] {
        assert!(err.contains(needle), "missing {needle} in {err}");
    }
    std::fs::write(&p, "[transport.zenoh]\nlisen = []\n").unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("check-config")
        .arg(&p)
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown field `lisen`"));
}
