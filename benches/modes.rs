//! The two ways to run one training, end to end, in one run of this benchmark: `fsrl train
//! --single-process` against `fsrl train` (a learner, actors and an evaluator as processes, the
//! iceoryx2 data plane), FSRL on env1-invisible, seed 0, the default (short) schedule, one after
//! the other with nothing else running. Prints each mode's wall-clock time split into warm
//! start, RL, validation and final evaluation (from the run's `run.json`), each process's
//! waiting in the distributed run, and the ratio distributed / single-process (issue 33's target:
//! ≤ 0.55). At the default schedule the single-process run is also exported and compared byte
//! for byte with the shipped `models/fsrl-env1-invisible-s0.fsrlm` (the run directory has the
//! shipped run's name, which the model records): the single-process mode still trains what was
//! shipped.
//!
//! `cargo bench -p fsrl --bench modes` (about 25 minutes on 2 cores). `FSRL_MODES_RL_EPISODES=N`
//! shortens the RL phase (and the ε decay to 2/5 of it) for a quick look; `FSRL_MODES_ACTORS`
//! sets the actors of the distributed run (default 2), which runs `fsrl train`'s default, the
//! adaptive replay ratio (4 to 20 updates per episode, Experiment 18); `FSRL_MODES_REPLAY_RATIO`
//! is its `--replay-ratio` (`fixed`: the 20 per episode of the single process, as before
//! Experiment 18); `FSRL_MODES_DIST_CONFIG=FILE` gives the distributed run a config of its own
//! (with `FSRL_MODES_RL_EPISODES` the file must shorten its RL phase itself); `FSRL_MODES_OUT=DIR` keeps both run directories in
//! `DIR/{single,distributed}/fsrl-env1-invisible-s0` instead of a temporary directory.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

fn run(mode: &[&str], out: &Path, config: Option<&Path>) -> (f64, serde_json::Value) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_fsrl"));
    c.args([
        "train",
        "--method",
        "fsrl",
        "--setting",
        "env1-invisible",
        "--seed",
        "0",
    ])
    .args(mode)
    .arg("--out")
    .arg(out);
    if let Some(cfg) = config {
        c.arg("--config").arg(cfg);
    }
    let t = Instant::now();
    let o = c.output().expect("fsrl runs");
    let wall = t.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
    (wall, run)
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let kept = std::env::var_os("FSRL_MODES_OUT").map(std::path::PathBuf::from);
    let dir = kept.as_deref().unwrap_or(tmp.path());
    let dist_config = std::env::var_os("FSRL_MODES_DIST_CONFIG").map(std::path::PathBuf::from);
    let config = std::env::var("FSRL_MODES_RL_EPISODES")
        .ok()
        .and_then(|v| v.parse::<u64>().ok())
        .map(|n| {
            let p = dir.join("short.toml");
            std::fs::write(
                &p,
                format!(
                    "[train.rl]\nepisodes = {n}\nepsilon_decay_episodes = {}\n",
                    (n * 2 / 5).max(1)
                ),
            )
            .unwrap();
            p
        });
    let actors = std::env::var("FSRL_MODES_ACTORS").unwrap_or_else(|_| "2".into());
    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!(
        "modes: FSRL env1-invisible seed 0, default schedule{}; load average before {}",
        config
            .as_ref()
            .map_or(String::new(), |_| " (RL shortened)".into()),
        load()
    );
    let single_dir = dir.join("single").join("fsrl-env1-invisible-s0");
    let (single_wall, single) = run(&["--single-process"], &single_dir, config.as_deref());
    if config.is_none() {
        let exported = dir.join("single.fsrlm");
        let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .arg("export-model")
            .arg(&single_dir)
            .arg("--out")
            .arg(&exported)
            .output()
            .expect("fsrl runs");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let shipped =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fsrl-env1-invisible-s0.fsrlm");
        let same = std::fs::read(&exported).ok() == std::fs::read(&shipped).ok();
        println!(
            "single-process model byte-identical to the shipped {}: {}",
            shipped.display(),
            if same { "yes" } else { "NO" }
        );
    }
    println!("load average after the single-process run: {}", load());
    let ratio = std::env::var("FSRL_MODES_REPLAY_RATIO").ok();
    let mut dist_args = vec!["--actors", actors.as_str()];
    if let Some(r) = &ratio {
        dist_args.extend(["--replay-ratio", r.as_str()]);
    }
    let (dist_wall, dist) = run(
        &dist_args,
        &dir.join("distributed").join("fsrl-env1-invisible-s0"),
        dist_config.as_deref().or(config.as_deref()),
    );
    println!("load average after the distributed run: {}", load());
    let f = |v: &serde_json::Value, k: &str| v.get(k).and_then(|x| x.as_f64()).unwrap_or(f64::NAN);
    if let Some(c) = &dist_config {
        println!("distributed run's config: {}", c.display());
    }
    println!(
        "distributed run's replay ratio: {}",
        dist.get("replay_ratio")
            .map_or("?".into(), |v| v.to_string())
    );
    println!("| part (s) | single-process | distributed ({actors} actors) |");
    println!("|---|---|---|");
    for k in [
        "warm_start_s",
        "rl_s",
        "validation_s",
        "final_evaluation_s",
        "total_s",
    ] {
        println!("| {k} | {:.1} | {:.1} |", f(&single, k), f(&dist, k));
    }
    println!("| wall clock of the command | {single_wall:.1} | {dist_wall:.1} |");
    for k in [
        "learner_wait_s",
        "learner_train_s",
        "learner_updates_per_episode",
        "learner_policy_lag_mean",
        "learner_policy_lag_p95",
        "actors_sim_s",
        "actors_wait_s",
        "evaluator_wait_s",
    ] {
        println!("| {k} | – | {:.2} |", f(&dist, k));
    }
    println!(
        "distributed / single-process, end to end: {:.3} (target <= 0.55)",
        dist_wall / single_wall
    );
}
