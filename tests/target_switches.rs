//! `fsrl+` (beyond the paper, docs/REPRODUCTION.md Experiment 19) end to end on the distributed
//! path: a learner, two actors and an evaluator train it, the learner takes every RL episode
//! (it must replay each episode's ε draws, which needs the run's action count), and the model
//! the run ships records the switches it was trained with.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn a_distributed_fsrl_plus_run_takes_every_episode_and_records_its_switches() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(["train", "--method", "fsrl+", "--setting", "env1-invisible"])
        .args(["--actors", "2", "--il-episodes", "8", "--il-epochs", "2"])
        .args(["--rl-episodes", "8", "--eval-episodes", "4", "--out"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // A learner that refused every episode would wait for them for ever: bounded here.
    let deadline = Instant::now() + Duration::from_secs(240);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("fsrl train --method fsrl+ did not finish within 240 s");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut stderr = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut stderr).unwrap();
    assert!(status.success(), "{stderr}");

    let lines: Vec<serde_json::Value> = std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let rl = lines.iter().filter(|v| v["phase"] == "rl").count();
    assert_eq!(rl, 8, "every RL episode taken by the learner");

    let model = dir.path().join("plus.fsrlm");
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
    assert_eq!(m.method, policy::method::Method::FsrlPlus);
    assert!(m.train.rl.greedy_targets, "{:?}", m.train.rl);
    assert_eq!(m.train.rl.n_step, policy::method::FSRL_PLUS_N_STEP);
    assert!(m.sim.reward.foresight && m.sim.reward.efficiency);
}
