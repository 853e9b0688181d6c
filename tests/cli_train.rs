//! `fsrl train` end to end: a short single-process run leaves a complete run directory, refuses
//! to overwrite it or to share it with a second training, resumes it, checkpoints on SIGINT, and
//! reports bad configuration at once.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn fsrl() -> Command {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
}

fn short(out: &Path) -> Command {
    let mut c = fsrl();
    c.args([
        "train",
        "--single-process",
        "--method",
        "sarl",
        "--setting",
        "env2-visible",
    ])
    .args([
        "--il-episodes",
        "8",
        "--il-epochs",
        "2",
        "--eval-episodes",
        "4",
        "--out",
    ])
    .arg(out);
    c
}

fn rl_lines(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["phase"] == "rl")
        .collect()
}

#[test]
fn a_short_run_leaves_a_complete_run_directory_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = short(&out).args(["--rl-episodes", "3"]).output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    for f in [
        "config.toml",
        "checkpoints/latest.ckpt",
        "checkpoints/imitation.ckpt",
        "report.md",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    let cfg = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(
        cfg.contains("method = \"sarl\"") && cfg.contains("setting = \"env2-visible\""),
        "{cfg}"
    );
    assert!(
        cfg.contains("foresight = true"),
        "the resolved file keeps the sim defaults:\n{cfg}"
    );
    let lines = rl_lines(&out);
    assert_eq!(lines.len(), 3);
    for (k, l) in lines.iter().enumerate() {
        assert_eq!(l["episode"], k as u64);
        assert!(l["loss"].as_f64().unwrap().is_finite());
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["settings"][0]["setting"], "env2-visible");
    assert_eq!(report["settings"][0]["episodes"], 4);
    let rates: f64 = ["success", "collision", "timeout"]
        .iter()
        .map(|k| report["settings"][0][k].as_f64().unwrap())
        .sum();
    assert!((rates - 1.0).abs() < 1e-9);
    assert!(stdout.contains("| env2-visible | 4 |"), "{stdout}");

    // The same command again refuses to overwrite the run.
    let o = short(&out).args(["--rl-episodes", "3"]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume"));

    // What a crash leaves after the last checkpoint (an RL episode and a validation the resumed
    // run does again, then a torn line) is cut away: no episode twice, no line swallowed.
    {
        use std::io::Write;
        let mut log = std::fs::OpenOptions::new()
            .append(true)
            .open(out.join("metrics.jsonl"))
            .unwrap();
        write!(
            log,
            "{}\n{}\n{{\"phase\":\"rl\",\"epi",
            serde_json::json!({"phase": "rl", "episode": 3, "loss": 0.5, "wall_s": 1e6}),
            serde_json::json!({"phase": "validation", "episode": 4, "success_rate": 0.0,
                "collision_rate": 1.0, "timeout_rate": 0.0, "episodes": 100, "seed_start": 0,
                "wall_s": 1e6}),
        )
        .unwrap();
    }
    // --resume continues where it stopped.
    let o = short(&out)
        .args(["--rl-episodes", "5", "--resume"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("3 RL episodes done"), "{stderr}");
    assert!(
        stderr.contains("dropped 3 lines logged after the checkpoint"),
        "{stderr}"
    );
    let lines = rl_lines(&out);
    let episodes: Vec<u64> = lines
        .iter()
        .map(|l| l["episode"].as_u64().unwrap())
        .collect();
    assert_eq!(episodes, vec![0, 1, 2, 3, 4]);
    // The learning curve: the greedy policy on the validation seeds after imitation, at the end
    // of the first invocation and at the end of the resumed one, on a clock that goes on.
    let validation: Vec<serde_json::Value> = std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["phase"] == "validation")
        .collect();
    let at: Vec<u64> = validation
        .iter()
        .map(|v| v["episode"].as_u64().unwrap())
        .collect();
    assert_eq!(at, vec![0, 3, 5]);
    for v in &validation {
        assert_eq!(v["episodes"], 100);
        assert_eq!(v["seed_start"], 0);
        let rates: f64 = ["success_rate", "collision_rate", "timeout_rate"]
            .iter()
            .map(|k| v[k].as_f64().unwrap())
            .sum();
        assert!((rates - 1.0).abs() < 1e-9, "{v}");
    }
    let wall: Vec<f64> = validation
        .iter()
        .map(|v| v["wall_s"].as_f64().unwrap())
        .collect();
    assert!(wall.windows(2).all(|w| w[0] < w[1]), "{wall:?}");
}

#[test]
fn sigint_writes_a_checkpoint_and_the_run_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut child = short(&out)
        .args(["--rl-episodes", "100000"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Ready when the first RL episode is logged.
    let deadline = Instant::now() + Duration::from_secs(120);
    while rl_lines(&out).is_empty() {
        assert!(Instant::now() < deadline, "no RL episode within 120 s");
        assert!(child.try_wait().unwrap().is_none(), "trainer exited early");
        std::thread::sleep(Duration::from_millis(50));
    }
    // A second training on the same run directory is refused while this one holds it.
    let second = short(&out)
        .args(["--resume", "--rl-episodes", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "{err}");
    assert!(
        err.contains(&child.id().to_string()),
        "names the holder: {err}"
    );
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let o = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("--resume"), "{stderr}");
    let done = rl_lines(&out).len() as u64;
    assert!(done >= 1);
    let loaded = learner::checkpoint::load(&out.join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(
        loaded.core.counters().rl_episodes,
        done,
        "the checkpoint holds every logged episode"
    );
    assert!(
        !out.join("report.json").exists(),
        "no evaluation after an interrupt"
    );
}

#[test]
fn bad_run_configuration_lists_every_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "[train]\ngamma = 1.5\n[train.rl]\nbatch_size = 0\n").unwrap();
    let o = fsrl()
        .args([
            "train",
            "--method",
            "dqn",
            "--setting",
            "env9-visible",
            "--config",
        ])
        .arg(&cfg)
        .arg("--out")
        .arg(dir.path().join("run"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    for needle in [
        "4 problems",
        "unknown method `dqn`",
        "unknown setting `env9-visible`",
        "train.gamma",
        "train.rl.batch_size",
    ] {
        assert!(stderr.contains(needle), "missing {needle:?} in\n{stderr}");
    }
}

#[test]
fn best_validation_selection_keeps_snapshots_and_the_run_uses_the_best() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("select.toml");
    std::fs::write(
        &cfg,
        "[train]\nselect = \"best-validation\"\nvalidation_every_episodes = 2\nvalidation_episodes = 10\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let o = short(&out)
        .arg("--config")
        .arg(&cfg)
        .args(["--rl-episodes", "6"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // One snapshot per validation, each a model file of that many RL episodes.
    let validation: Vec<serde_json::Value> = std::fs::read_to_string(out.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["phase"] == "validation")
        .collect();
    let at: Vec<u64> = validation
        .iter()
        .map(|v| v["episode"].as_u64().unwrap())
        .collect();
    assert_eq!(at, vec![0, 2, 4, 6]);
    for ep in &at {
        let snap = out.join(format!("checkpoints/validation/ep-{ep:06}.fsrlm"));
        assert!(snap.is_file(), "missing {}", snap.display());
    }
    // The best by success, then fewer collisions, then the earliest, worked out here.
    let key = |v: &serde_json::Value| {
        (
            v["success_rate"].as_f64().unwrap(),
            -v["collision_rate"].as_f64().unwrap(),
        )
    };
    let best = validation
        .iter()
        .fold(None::<&serde_json::Value>, |b, v| match b {
            Some(b) if key(v) <= key(b) => Some(b),
            _ => Some(v),
        })
        .unwrap()["episode"]
        .as_u64()
        .unwrap();
    let said = format!("the snapshot after {best} RL episodes");
    assert!(stderr.contains(&said), "final evaluation: {stderr}");
    // export-model of the run directory writes that snapshot's weights.
    let model = dir.path().join("m.fsrlm");
    let export = |extra: &[&str]| -> String {
        let o = fsrl()
            .arg("export-model")
            .arg(&out)
            .arg("--out")
            .arg(&model)
            .args(["--check-episodes", "1"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let stdout = export(&[]);
    assert!(
        stdout.contains(&format!(", {best} RL episodes,"))
            && stdout.contains("chosen by train.select = \"best-validation\""),
        "exported {stdout}"
    );
    // --select overrides the run's rule: the last weights are those of all 6 episodes.
    let stdout = export(&["--select", "last"]);
    assert!(
        stdout.contains(", 6 RL episodes,") && stdout.contains("chosen by train.select = \"last\""),
        "the model records the rule that chose it: {stdout}"
    );
    let o = fsrl()
        .arg("eval")
        .arg(&out)
        .args(["--select", "gentlest"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && stderr.contains("not one of last, best-validation, low-disc"),
        "{stderr}"
    );

    // The same rule in a distributed run: the evaluator process keeps each validated snapshot
    // (before its line), the run's policy is chosen from them as in one process, and run.json
    // says which mode made the run and the replay ratio the learner realised.
    let dist = dir.path().join("dist");
    let o = fsrl()
        .args([
            "train",
            "--method",
            "sarl",
            "--setting",
            "env2-visible",
            "--actors",
            "2",
        ])
        .args([
            "--il-episodes",
            "8",
            "--il-epochs",
            "2",
            "--eval-episodes",
            "4",
        ])
        .args(["--rl-episodes", "6", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&dist)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(dist.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .collect();
    let validated: Vec<u64> = lines
        .iter()
        .filter(|v| v["phase"] == "validation")
        .map(|v| v["episode"].as_u64().unwrap())
        .collect();
    // The final weights carry all 6 episodes, also when the last one came after the last round
    // of updates and they repeat that round's version (`Control::final_rl_episodes`).
    assert!(
        validated.first() == Some(&0) && validated.last() == Some(&6),
        "the first and the final weights are validated: {validated:?}"
    );
    for ep in &validated {
        let snap = dist.join(format!("checkpoints/validation/ep-{ep:06}.fsrlm"));
        assert!(snap.is_file(), "missing {}", snap.display());
    }
    assert!(
        stderr.contains("train.select = \"best-validation\": the snapshot after"),
        "the final evaluation uses the chosen snapshot: {stderr}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dist.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["settings"][0]["setting"], "env2-visible");
    assert_eq!(report["settings"][0]["episodes"], 4);
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dist.join("run.json")).unwrap()).unwrap();
    assert_eq!(run["mode"], "distributed", "{run}");
    // The default of a distributed `fsrl train`: the adaptive replay ratio, 4 to 20 updates per
    // episode (Experiment 18).
    assert_eq!(
        run["replay_ratio"],
        serde_json::json!({"min": 4.0, "max": 20.0}),
        "{run}"
    );
    let realised = run["learner_updates_per_episode"].as_f64().unwrap();
    assert!((4.0..=20.0).contains(&realised), "{run}");
    // export-model works on the distributed run as on the single-process one.
    let o = fsrl()
        .arg("export-model")
        .arg(&dist)
        .arg("--out")
        .arg(dir.path().join("d.fsrlm"))
        .args(["--check-episodes", "1"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && stdout.contains("chosen by train.select = \"best-validation\""),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Issue 44: a bad replay ratio is refused with one line before anything is written or
/// started, whether a flag (`--replay-ratio`), a config file (bounds that do not fit its
/// `batches_per_episode`) or a resumed run's own `config.toml` says it. Before, all but the
/// unparsable ones started every process and were refused by the learner, and stayed in the
/// run's config.
#[test]
fn a_bad_replay_ratio_is_refused_before_anything_starts() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let refused = |args: &[&str], says: &str| {
        let o = fsrl().arg("train").args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?}: {stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
        assert!(
            errors.len() == 1 && errors[0].contains(says),
            "{args:?}: one line naming {says}:\n{stderr}"
        );
        stderr.into_owned()
    };
    let o = out.to_str().unwrap();
    for bad in ["5,1", "-1,4", "nan", "0,0", "inf"] {
        refused(&["--replay-ratio", bad, "--out", o], "--replay-ratio");
        assert!(!out.exists(), "{bad}: the run directory was written");
    }
    // The default bounds with a config that cannot have them.
    let cfg = dir.path().join("zero.toml");
    std::fs::write(&cfg, "[train.rl]\nbatches_per_episode = 0\n").unwrap();
    let c = cfg.to_str().unwrap();
    refused(&["--config", c, "--out", o], "batches_per_episode");
    assert!(!out.exists(), "the run directory was written");
    // A run whose own config.toml has bounds no run can have (written by an older fsrl).
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(
        out.join("config.toml"),
        "[train.rl]\nreplay_ratio = { min = 5, max = 1 }\n",
    )
    .unwrap();
    refused(&["--resume", "--out", o], "config.toml");
    assert!(!out.join("logs").exists(), "processes were started");
}

/// Issue 44: `--single-process --resume` of a run trained as a distributed run in the adaptive
/// mode (the default) says so, and what to do; it used to ask the user to drop a
/// `replay_ratio` line they never wrote.
#[test]
fn a_default_distributed_run_does_not_resume_in_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let cfg = sim::SimConfig::default();
    let mut train = policy::method::TrainConfig::default();
    train.rl.replay_ratio = Some(policy::method::ReplayRatio::LOCAL_DEFAULT);
    let core = learner::LearnerCore::new(
        policy::method::Method::Sarl,
        train,
        cfg.humans.count,
        cfg.dt_s,
        0,
    )
    .unwrap();
    let run = learner::checkpoint::RunInfo {
        run_id: "run".into(),
        setting: "env1-invisible".into(),
        run_seed: 0,
        accepted_below: Default::default(),
    };
    std::fs::create_dir_all(out.join("checkpoints")).unwrap();
    learner::checkpoint::save(&out.join("checkpoints/latest.ckpt"), &core, &cfg, &run).unwrap();
    let o = fsrl()
        .args(["train", "--single-process", "--resume", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{stderr}");
    assert!(
        stderr.contains("trained as a distributed run")
            && stderr.contains("without --single-process")
            && !stderr.contains("replay_ratio line"),
        "{stderr}"
    );
    assert!(
        !out.join("config.toml").exists(),
        "the run's config was written"
    );
}

/// A tiny distributed run (one actor, no evaluator, over zenoh) with `--dashboard PORT`: its
/// output and its stderr as text.
fn tiny_with_page(out: &Path, port: u16) -> (std::process::Output, String) {
    let o = fsrl()
        .args([
            "train",
            "--method",
            "sarl",
            "--il-episodes",
            "4",
            "--il-epochs",
            "1",
        ])
        .args([
            "--rl-episodes",
            "2",
            "--eval-episodes",
            "2",
            "--actors",
            "1",
        ])
        .args(["--no-evaluator", "--transport", "zenoh", "--no-tensorboard"])
        .args(["--dashboard", &port.to_string(), "--out"])
        .arg(out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    (o, stderr)
}

/// Issue 52: `--dashboard 0` serves the page on a free port and says which, not port 0.
#[test]
fn the_live_page_on_port_0_is_announced_on_the_port_it_serves() {
    let dir = tempfile::tempdir().unwrap();
    let (o, stderr) = tiny_with_page(&dir.path().join("run"), 0);
    assert!(o.status.success(), "{stderr}");
    let port = stderr
        .lines()
        .find_map(|l| l.strip_prefix("live page: http://127.0.0.1:"))
        .and_then(|p| p.trim_end_matches('/').parse::<u16>().ok());
    assert!(
        port.is_some_and(|p| p != 0),
        "the page's real port:\n{stderr}"
    );
}

/// Issue 52: a page that cannot be served (its port in use) is an error the user sees, before
/// anything starts; it used to be written to logs/dashboard.log alone while the run went on.
#[test]
fn a_live_page_port_in_use_is_refused_before_anything_starts() {
    let port = testkit::free_port();
    let _taken = std::net::TcpListener::bind(("127.0.0.1", port)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (o, stderr) = tiny_with_page(&out, port);
    assert!(!o.status.success(), "{stderr}");
    assert!(
        stderr.contains(&format!("cannot serve the live page on 127.0.0.1:{port}")),
        "{stderr}"
    );
    assert!(!out.join("logs").exists(), "processes were started");
}

/// Issue 54: a default distributed run (no `[train] select`) chooses by `revalidated-return`:
/// its candidates (the best validation returns after the ε decay, and the last weights) are each
/// scored again on the re-validation seeds, every result is a line of `revalidation.jsonl`, the
/// policy is the best re-validated return (ties: the later), the report lists them, and an
/// export reuses the file, re-validating only what an interruption left out.
#[test]
fn a_default_distributed_run_chooses_by_the_revalidated_return() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("reval.toml");
    std::fs::write(
        &cfg,
        "[train]\nvalidation_every_episodes = 2\nvalidation_episodes = 10\n\
         [train.rl]\nepsilon_decay_episodes = 0\n\
         [train.revalidation]\ntop = 2\nepisodes = 6\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let o = fsrl()
        .args(["train", "--method", "sarl", "--setting", "env2-visible"])
        .args(["--actors", "1", "--il-episodes", "8", "--il-epochs", "2"])
        .args(["--eval-episodes", "4", "--rl-episodes", "6", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let config = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(
        config.contains("select = \"revalidated-return\""),
        "{config}"
    );
    // The candidates, worked out here from the validations: the 2 best returns (ties: the
    // later) and the last weights.
    // One per RL episode count: the later line of a repeated validation.
    let validations: std::collections::BTreeMap<u64, f64> =
        std::fs::read_to_string(out.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .filter(|v| v["phase"] == "validation")
            .map(|v| {
                (
                    v["episode"].as_u64().unwrap(),
                    v["mean_return"].as_f64().unwrap(),
                )
            })
            .collect();
    let mut ranked: Vec<(u64, f64)> = validations.clone().into_iter().collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(b.0.cmp(&a.0)));
    let mut candidates: Vec<u64> = ranked.iter().take(2).map(|v| v.0).collect();
    let last = *validations.keys().max().unwrap();
    candidates.push(last);
    candidates.sort();
    candidates.dedup();
    assert!(candidates.len() >= 2, "{validations:?}");
    let read = || -> Vec<serde_json::Value> {
        std::fs::read_to_string(out.join("revalidation.jsonl"))
            .unwrap()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    };
    let lines = read();
    let scored: Vec<u64> = lines
        .iter()
        .map(|l| l["rl_episodes"].as_u64().unwrap())
        .collect();
    assert_eq!(scored, candidates, "{lines:?}");
    for l in &lines {
        assert_eq!(
            (l["seed_start"].as_u64(), l["episodes"].as_u64()),
            (Some(10_000), Some(6))
        );
        assert_eq!(l["last"].as_bool(), Some(l["rl_episodes"] == last));
    }
    let best = lines
        .iter()
        .max_by(|a, b| {
            let key = |l: &serde_json::Value| {
                (
                    l["mean_return"].as_f64().unwrap(),
                    l["rl_episodes"].as_u64().unwrap(),
                )
            };
            key(a).partial_cmp(&key(b)).unwrap()
        })
        .unwrap();
    let chosen = best["rl_episodes"].as_u64().unwrap();
    assert!(
        stderr.contains(&format!(
            "train.select = \"revalidated-return\": the snapshot after {chosen} RL episodes"
        )),
        "the final evaluation uses the best re-validated snapshot ({chosen}): {stderr}"
    );
    // The line's figures are the snapshot's on the re-validation seeds.
    let eval_dir = dir.path().join("eval");
    let o = fsrl()
        .arg("eval")
        .arg(out.join(format!("checkpoints/validation/ep-{chosen:06}.fsrlm")))
        .args([
            "--settings",
            "env2-visible",
            "--episodes",
            "6",
            "--seed-start",
            "10000",
        ])
        .arg("--out")
        .arg(&eval_dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval_dir.join("eval.json")).unwrap())
            .unwrap();
    let r = eval["subjects"][0]["settings"][0]["mean_return"]
        .as_f64()
        .unwrap();
    assert!(
        (r - best["mean_return"].as_f64().unwrap()).abs() < 1e-9,
        "{r} {best}"
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains(&format!(
            "{} candidates × 6 validation episodes (seeds 10000..10005)",
            candidates.len()
        )) && report.contains("← the policy"),
        "{report}"
    );
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
    assert!(run["revalidation_s"].as_f64().unwrap() > 0.0, "{run}");
    // export-model reuses the file: the same choice, nothing re-validated.
    let before = std::fs::read(out.join("revalidation.jsonl")).unwrap();
    let export = || {
        let o = fsrl()
            .arg("export-model")
            .arg(&out)
            .arg("--out")
            .arg(dir.path().join("m.fsrlm"))
            .args(["--check-episodes", "1"])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
        let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
        assert!(o.status.success(), "{stderr}");
        assert!(
            stdout.contains(&format!(", {chosen} RL episodes,"))
                && stdout.contains("chosen by train.select = \"revalidated-return\""),
            "{stdout}"
        );
        stderr
    };
    let said = export();
    assert!(!said.contains("re-validating"), "{said}");
    assert_eq!(
        std::fs::read(out.join("revalidation.jsonl")).unwrap(),
        before
    );
    // Interrupted during the re-validation: the first line and half of the second were
    // written. The export re-validates the rest only, and chooses the same.
    let text = String::from_utf8(before).unwrap();
    let kept: Vec<&str> = text.lines().collect();
    std::fs::write(
        out.join("revalidation.jsonl"),
        format!("{}\n{}", kept[0], &kept[1][..kept[1].len() / 2]),
    )
    .unwrap();
    let said = export();
    assert!(
        said.contains(&format!(
            "re-validating {} candidate snapshot(s)",
            candidates.len() - 1
        )),
        "{said}"
    );
    let again: Vec<u64> = read()
        .iter()
        .map(|l| l["rl_episodes"].as_u64().unwrap())
        .collect();
    assert_eq!(again.len(), candidates.len(), "{again:?}");
}
