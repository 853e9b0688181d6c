//! `fsrl sim` end to end: the real binary, its table, its picture and its errors.

use std::process::Command;

fn fsrl() -> Command {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
}

#[test]
fn sim_prints_the_table_and_writes_a_valid_picture() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("episode.svg");
    let out = fsrl()
        .args([
            "sim",
            "--episodes",
            "20",
            "--settings",
            "env1-invisible,env3-visible",
        ])
        .args([
            "--svg-setting",
            "env3-visible",
            "--svg-seed",
            "1004",
            "--svg",
        ])
        .arg(&svg)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for needle in [
        "| env1-invisible |",
        "| env3-visible |",
        "Succ.",
        "Disc.",
        "wrote",
    ] {
        assert!(stdout.contains(needle), "missing {needle:?} in\n{stdout}");
    }
    // Every rate is a number in [0, 1] and the three outcome rates sum to 1.
    let row = stdout
        .lines()
        .find(|l| l.starts_with("| env1-invisible |"))
        .unwrap();
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let rates: Vec<f64> = cells[2..5].iter().map(|c| c.parse().unwrap()).collect();
    assert!((rates.iter().sum::<f64>() - 1.0).abs() < 1e-9, "{row}");

    let text = std::fs::read_to_string(&svg).unwrap();
    let doc = roxmltree::Document::parse(&text).expect("the picture is well-formed XML");
    assert_eq!(doc.root_element().tag_name().name(), "svg");
    // viz's episode picture (as `fsrl plot episode` draws it): panels at a third, two thirds
    // and the end of the episode.
    let count = |tag: &str, attrs: &[(&str, &str)]| {
        doc.descendants()
            .filter(|n| {
                n.has_tag_name(tag) && attrs.iter().all(|(k, v)| n.attribute(*k) == Some(*v))
            })
            .count()
    };
    let words: String = doc
        .descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text())
        .collect();
    assert_eq!(words.matches("t = ").count(), 3, "{words}");
    // Env 3: in every panel the 5 dynamic humans have a path so far, the robot a bold one.
    assert_eq!(
        count("polyline", &[("opacity", "0.45")]),
        3 * 5,
        "human paths"
    );
    let robot_path = [("stroke", "#E67E22"), ("stroke-width", "3")];
    assert_eq!(count("polyline", &robot_path), 3, "robot paths");
    // Five standing humans per panel, plus the legend's square.
    assert_eq!(
        count("polygon", &[("fill", "#707070")]),
        3 * 5,
        "standing humans"
    );
    assert_eq!(count("rect", &[("fill", "#707070")]), 1, "legend");
    assert!(
        words.contains("ORCA robot on env3-visible, seed 1004"),
        "{words}"
    );
}

#[test]
fn bad_configuration_lists_every_problem_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("bad.toml");
    std::fs::write(
        &cfg,
        "[sim]\ndt_s = -0.25\n[sim.robot]\nradius_m = nan\n[sim.humans]\nstanding = 12\n",
    )
    .unwrap();
    let out = fsrl()
        .args([
            "sim",
            "--episodes",
            "1",
            "--settings",
            "env1-visible,env7-visible",
            "--config",
        ])
        .arg(&cfg)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    for needle in [
        "4 problems",
        "dt_s must be > 0",
        "robot.radius_m must be a finite number",
        "humans.standing (12) must not exceed humans.count (10)",
        "unknown setting `env7-visible`",
    ] {
        assert!(stderr.contains(needle), "missing {needle:?} in\n{stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn unknown_config_keys_and_missing_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("typo.toml");
    std::fs::write(&cfg, "[sim.humans]\ncount = 10\nradius = 0.3\n").unwrap();
    let out = fsrl().args(["sim", "--config"]).arg(&cfg).output().unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("unknown field `radius`"), "{stderr}");

    let out = fsrl()
        .args(["sim", "--config", "/nonexistent/fsrl.toml"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("cannot read config file /nonexistent/fsrl.toml"),
        "{stderr}"
    );
}
