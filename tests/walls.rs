//! Issue 53 end to end: a walled setting trains through the default distributed path (learner,
//! two actors over iceoryx2, the evaluator process) and its report splits wall and people
//! collisions and counts frozen robots.

use std::path::Path;
use std::process::Command;

/// `fsrl train ARGS --no-tensorboard --out OUT`, which must succeed: its stdout and stderr.
fn train(args: &[&str], out: &Path) -> (String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("train")
        .args(args)
        .args(["--no-tensorboard", "--out"])
        .arg(out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{stdout}\n{stderr}");
    (stdout, stderr)
}

#[test]
fn a_walled_setting_trains_end_to_end_through_the_distributed_path() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (stdout, stderr) = train(
        &[
            "--method",
            "fsrl",
            "--setting",
            "doorway",
            "--il-episodes",
            "6",
            "--il-epochs",
            "1",
            "--rl-episodes",
            "8",
            "--eval-episodes",
            "6",
        ],
        &out,
    );
    assert!(
        stderr.contains("actor process") || stdout.contains("actor process"),
        "not the distributed path:\n{stdout}\n{stderr}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let text = report.to_string();
    let setting = report["settings"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["setting"] == "doorway"))
        .unwrap_or_else(|| panic!("no doorway setting in the report: {text}"));
    assert_eq!(setting["episodes"], 6, "{text}");
    // The wall fields sit beside the others (flattened), only in walled settings.
    let walls = setting;
    for key in ["wall_collisions", "people_collisions", "frozen_robots"] {
        assert!(walls[key].is_u64(), "no {key} in {text}");
    }
    let split =
        walls["wall_collisions"].as_u64().unwrap() + walls["people_collisions"].as_u64().unwrap();
    assert_eq!(split, setting["collisions"].as_u64().unwrap(), "{text}");
}

/// The single-process path trains a walled setting too (its learner sees the person slots and
/// obstacle sectors: `SimConfig::entities`; it refused with "18 humans, this run has 10").
#[test]
fn a_walled_setting_trains_in_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    train(
        &[
            "--single-process",
            "--method",
            "sarl",
            "--setting",
            "corridor",
            "--il-episodes",
            "4",
            "--il-epochs",
            "1",
            "--rl-episodes",
            "3",
            "--eval-episodes",
            "3",
        ],
        &out,
    );
    let report = std::fs::read_to_string(out.join("report.json")).unwrap();
    assert!(report.contains("\"wall_collisions\""), "{report}");
}
