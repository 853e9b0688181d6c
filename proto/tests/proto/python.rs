//! Metrics are readable by field name from Python's `msgpack` (what CI runs).

use std::path::Path;
use std::process::Command;

use proto::{encode, fixtures, Metrics, SenderId};

#[test]
fn metrics_are_readable_from_python() {
    let have_msgpack = Command::new("python3")
        .args(["-c", "import msgpack"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    assert!(
        have_msgpack,
        "python3 with the `msgpack` module is required for this test: pip install msgpack"
    );

    let header = fixtures::header::<Metrics>(SenderId::learner(), 3, 42);
    let bytes = encode(&header, &fixtures::metrics()).expect("encode");
    let dir = tempfile::tempdir().expect("tempdir");
    let file = dir.path().join("metrics.msgpack");
    std::fs::write(&file, &bytes).expect("write");

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/decode_metrics.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(&file)
        .output()
        .expect("run python3");
    assert!(
        out.status.success(),
        "{} failed:\nstdout: {}\nstderr: {}",
        script.display(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
