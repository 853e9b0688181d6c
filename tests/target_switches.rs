//! The value-target switches (`train.rl.greedy_targets`, `train.rl.n_step`; docs/REPRODUCTION.md
//! Experiment 19) end to end on the distributed path: a learner, two actors and an evaluator
//! train with them from a config file, the learner takes every RL episode (it replays each
//! episode's ε draws, which needs the run's action count: without it every episode would be
//! refused), and the model the run ships records the switches it was trained with.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_distributed_run_with_the_target_switches_takes_every_episode_and_records_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let cfg = dir.path().join("switches.toml");
    std::fs::write(&cfg, "[train.rl]\ngreedy_targets = true\nn_step = 4\n").unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(["train", "--method", "fsrl", "--setting", "env1-invisible"])
        .args(["--actors", "2", "--il-episodes", "8", "--il-epochs", "2"])
        .args(["--rl-episodes", "8", "--eval-episodes", "4", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Read while it runs, so that a full pipe cannot hold the run up.
    let mut pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = std::io::Read::read_to_string(&mut pipe, &mut text);
        text
    });
    // A learner that refused every episode would wait for them for ever: bounded here.
    let deadline = Instant::now() + Duration::from_secs(240);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("fsrl train with the target switches did not finish within 240 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let stderr = reader.join().unwrap();
    assert!(status.success(), "{stderr}");

    let lines: Vec<serde_json::Value> = std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let rl = lines.iter().filter(|v| v["phase"] == "rl").count();
    assert_eq!(rl, 8, "every RL episode taken by the learner");

    let model = dir.path().join("switches.fsrlm");
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .arg("export-model")
        .arg(&out)
        .arg("--out")
        .arg(&model)
        .args(["--check-episodes", "1"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let m = learner::model::Model::load(&model).unwrap();
    assert!(m.train.rl.greedy_targets, "{:?}", m.train.rl);
    assert_eq!(m.train.rl.n_step, 4);
}
