//! TensorBoard files of a training run (`tboard`), read back with Python's `tensorboard` package
//! (its `EventAccumulator`, installed into .venv/ by tools/test.sh): every tag of the issue, at
//! the steps and with the values of the run's `metrics.jsonl` (and, for the distributed run's
//! live-only values, of the learner's messages in `processes.jsonl`); a single-process run
//! killed past its last checkpoint and resumed, with no step twice and every point at its log
//! line's time; `fsrl watch --tensorboard` on a live distributed run; and the files' names
//! (issue 52): a rebuild's temporary file is none TensorBoard reads, and event files sort in the
//! order they were started.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;
use testkit::Reaped;

type Points = BTreeMap<String, Vec<(i64, f64)>>;

fn fsrl() -> Command {
    Command::new(env!("CARGO_BIN_EXE_fsrl"))
}

const SHORT: [&str; 10] = [
    "--method",
    "sarl",
    "--setting",
    "env2-visible",
    "--il-episodes",
    "8",
    "--il-epochs",
    "2",
    "--eval-episodes",
    "4",
];

/// A run config with short validations, in `dir`.
fn config(dir: &Path) -> std::path::PathBuf {
    let cfg = dir.join("short.toml");
    std::fs::write(
        &cfg,
        "[train]\nvalidation_every_episodes = 4\nvalidation_episodes = 5\n",
    )
    .unwrap();
    cfg
}

/// Every scalar of the event files in `dir`, as TensorBoard's own reader sees them.
fn tensorboard_scalars(dir: &Path) -> Points {
    tensorboard_points(dir)
        .into_iter()
        .map(|(tag, p)| (tag, p.into_iter().map(|(s, v, _)| (s, v)).collect()))
        .collect()
}

/// Every scalar of the event files in `dir` as (step, value, wall time), as TensorBoard's own
/// reader sees them.
fn tensorboard_points(dir: &Path) -> BTreeMap<String, Vec<(i64, f64, f64)>> {
    let script = r#"
import json, sys
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
ea = EventAccumulator(sys.argv[1], size_guidance={"scalars": 0})
ea.Reload()
print(json.dumps({t: [[e.step, e.value, e.wall_time] for e in ea.Scalars(t)] for t in ea.Tags()["scalars"]}))
"#;
    let o = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(dir)
        .output()
        .expect("python3 (tools/test.sh puts .venv/ with `tensorboard` first on PATH)");
    assert!(
        o.status.success(),
        "reading {} with tensorboard's EventAccumulator failed (is `tensorboard` installed? tools/test.sh installs it into .venv/):\n{}",
        dir.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).expect("the reader's JSON")
}

fn lines(path: &Path) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// Episodes per second over the last ten intervals of `walls` (what `tboard` documents).
fn rate(walls: &[f64]) -> Option<f64> {
    let w = &walls[walls.len().saturating_sub(11)..];
    let (first, last) = (*w.first()?, *w.last()?);
    (w.len() >= 2 && last > first).then(|| (w.len() - 1) as f64 / (last - first))
}

/// What the tags must hold, worked out from the log here, independently of `tboard`'s code.
fn expected(log: &[Value], single_updates_per_episode: Option<f64>) -> Points {
    let mut p = Points::new();
    let mut put = |tag: &str, step: i64, v: Option<f64>| {
        if let Some(v) = v {
            p.entry(tag.to_string()).or_default().push((step, v));
        }
    };
    let mut walls = Vec::new();
    let mut actor_walls: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    let mut validated = std::collections::BTreeSet::new();
    for v in log {
        let f = |k: &str| v[k].as_f64();
        match v["phase"].as_str() {
            Some("imitation") => put(
                "losses/imitation_loss",
                v["epoch"].as_i64().unwrap() + 1,
                f("loss"),
            ),
            Some("rl") => {
                let step = v["episode"].as_i64().unwrap() + 1;
                put("losses/td_loss", step, f("loss"));
                put("charts/episodic_return", step, f("return_sum"));
                put("charts/epsilon", step, f("epsilon"));
                for rate in ["success", "collision", "timeout"] {
                    let key = format!("{rate}_rate_window");
                    put(&format!("charts/{key}"), step, f(&key));
                }
                walls.push(f("wall_s").unwrap());
                put("perf/episodes_per_s", step, rate(&walls));
                let actor = v["actor"].as_u64().unwrap_or(0);
                let aw = actor_walls.entry(actor).or_default();
                aw.push(f("wall_s").unwrap());
                put(
                    &format!("perf/episodes_per_s/actor_{actor}"),
                    step,
                    rate(aw),
                );
                if let Some(u) = single_updates_per_episode {
                    put("train/updates_per_episode", step, Some(u));
                    put("train/policy_lag_mean", step, Some(0.0));
                    put("train/policy_lag_max", step, Some(0.0));
                    put("perf/actors_alive", step, Some(1.0));
                }
            }
            Some("validation") => {
                let step = v["episode"].as_i64().unwrap();
                if !validated.insert(step) {
                    continue;
                }
                put("validation/success_rate", step, f("success_rate"));
                put("validation/collision_rate", step, f("collision_rate"));
                put("validation/timeout_rate", step, f("timeout_rate"));
                put("validation/discomfort", step, f("discomfort"));
                put("validation/nav_time_s", step, f("nav_time_s"));
                put("validation/mean_return", step, f("mean_return"));
            }
            _ => {}
        }
    }
    p
}

/// The learner's live-only values as the launcher received them (`processes.jsonl`): the first
/// message at each new RL episode count.
fn expected_live(processes: &[Value]) -> Points {
    let mut p = Points::new();
    let mut last = 0;
    for m in processes {
        if !m["sender"].as_str().unwrap_or("").starts_with("learner") {
            continue;
        }
        let values = &m["values"];
        let episodes = m["episodes"].as_i64().unwrap();
        if values["imitation_done"].as_f64() != Some(1.0) || episodes <= last {
            continue;
        }
        last = episodes;
        for (tag, key) in [
            ("train/updates_per_episode", "updates_per_episode"),
            ("train/policy_lag_mean", "policy_lag_mean"),
            ("train/policy_lag_max", "policy_lag_max"),
            ("perf/actors_alive", "actors_alive"),
        ] {
            if let Some(v) = values[key].as_f64() {
                p.entry(tag.to_string()).or_default().push((episodes, v));
            }
        }
    }
    p
}

/// The tags every run's files hold (the issue's list).
const TAGS: [&str; 11] = [
    "validation/success_rate",
    "validation/collision_rate",
    "validation/timeout_rate",
    "validation/discomfort",
    "losses/td_loss",
    "losses/imitation_loss",
    "perf/episodes_per_s",
    "perf/episodes_per_s/actor_0",
    "train/updates_per_episode",
    "train/policy_lag_mean",
    "perf/actors_alive",
];

/// `tb` holds every tag of `want` at exactly its steps, with its values (as f32).
fn assert_holds(tb: &Points, want: &Points) {
    for (tag, points) in want {
        let got = tb
            .get(tag)
            .unwrap_or_else(|| panic!("no tag {tag} in {:?}", tb.keys()));
        let steps: Vec<i64> = got.iter().map(|p| p.0).collect();
        let want_steps: Vec<i64> = points.iter().map(|p| p.0).collect();
        assert_eq!(steps, want_steps, "{tag}: steps");
        for ((s, g), (_, w)) in got.iter().zip(points) {
            assert!(
                (*g - (*w as f32) as f64).abs() <= 1e-6 * w.abs().max(1.0),
                "{tag} at step {s}: {g} in the event files, {w} in the log"
            );
        }
    }
}

fn assert_steps_rise(tb: &Points) {
    for (tag, points) in tb {
        assert!(
            points.windows(2).all(|w| w[0].0 < w[1].0),
            "{tag}: a step twice or out of order: {points:?}"
        );
    }
}

fn assert_every_tag(tb: &Points) {
    for tag in TAGS {
        assert!(
            tb.get(tag).is_some_and(|p| !p.is_empty()),
            "no {tag} in {:?}",
            tb.keys()
        );
    }
}

#[test]
fn a_single_process_run_killed_and_resumed_shows_one_curve() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    let out = dir.path().join("single");
    let train = |rl: &str| {
        let mut c = fsrl();
        c.args(["train", "--single-process"])
            .args(SHORT)
            .args(["--checkpoint-every", "4", "--rl-episodes", rl, "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out);
        c
    };
    // Killed just past a checkpoint, once the event files have caught up with its log: the log
    // and the files then hold episodes the checkpoint does not.
    let mut child = Reaped(
        train("100000")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let deadline = Instant::now() + Duration::from_secs(300);
    let tb_steps = |tag: &str| -> Vec<i64> {
        tboard::writer::read_dir(&out.join("tb"))
            .unwrap_or_default()
            .into_iter()
            .filter(|s| s.tag == tag)
            .map(|s| s.step)
            .collect()
    };
    let killed_at = loop {
        assert!(Instant::now() < deadline, "the run did not get far enough");
        assert!(child.0.try_wait().unwrap().is_none(), "the run stopped");
        let n = lines(&out.join("metrics.jsonl"))
            .iter()
            .filter(|v| v["phase"] == "rl")
            .count() as i64;
        if n >= 5 && n % 4 == 1 && tb_steps("losses/td_loss").last() == Some(&n) {
            child.0.kill().unwrap();
            child.0.wait().unwrap();
            break n;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let before = tb_steps("losses/td_loss");
    assert!(before.len() as i64 >= killed_at, "{before:?}");

    let target = killed_at + 3;
    let o = train(&target.to_string()).arg("--resume").output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let from: i64 = stderr
        .split(" RL episodes done")
        .next()
        .and_then(|s| s.rsplit(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no `N RL episodes done` in {stderr}"));
    assert!(
        from < killed_at,
        "the resumed run went on from {from}, the files had {killed_at}: nothing was trained twice"
    );

    let tb = tensorboard_scalars(&out.join("tb"));
    assert_every_tag(&tb);
    assert_steps_rise(&tb);
    let log = lines(&out.join("metrics.jsonl"));
    let want = expected(&log, Some(20.0));
    assert_eq!(
        want["losses/td_loss"]
            .iter()
            .map(|p| p.0)
            .collect::<Vec<_>>(),
        (1..=target).collect::<Vec<_>>()
    );
    assert_holds(&tb, &want);
    // Nothing in the files that is not in the log (the points of the killed run's lost
    // episodes went with them).
    assert_eq!(
        tb.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>()
    );
    assert_eq!(
        tboard::writer::event_files(&out.join("tb")).unwrap().len(),
        1,
        "the rebuilt directory holds one file"
    );
    // Every point at its log line's time (issue 52: the rebuild gave the killed run's points
    // the times they were polled at, and the resumed run's its own): TensorBoard's wall-time
    // axis is the run's clock, `wall_s`.
    let walls: Vec<f64> = log
        .iter()
        .filter(|v| v["phase"] == "rl")
        .map(|v| v["wall_s"].as_f64().unwrap())
        .collect();
    let times: Vec<f64> = tensorboard_points(&out.join("tb"))["losses/td_loss"]
        .iter()
        .map(|p| p.2)
        .collect();
    testkit::assert_same_spacing(&times, &walls, "TensorBoard's td_loss");
}

/// A `tb/` directory as TensorBoard's reader sees it: `x` at steps 1..=3 (value 1) in a file of
/// process 99999, then a rebuild of process 100000 in the same second (a session start, steps
/// 1..=2 at value 2), and a rebuild's temporary file a crash left (steps 1..=5 at value 9).
/// TensorBoard reads the files in name order and reads every name with `tfevents` in it:
/// issue 52, the pid was not padded (100000's file sorted first) and the temporary file's name
/// held `tfevents`.
#[test]
fn tensorboard_reads_the_files_in_start_order_and_no_temporary_file() {
    use tboard::writer::{self, EventWriter};
    let dir = tempfile::tempdir().unwrap();
    let tb = &dir.path().join("tb");
    std::fs::create_dir_all(tb).unwrap();
    let x = |step, value| tboard::Scalar {
        tag: "x".into(),
        step,
        value,
        wall_time: 1.7e9 + step as f64,
    };
    let mut first =
        EventWriter::create(&tb.join(writer::file_name(1_700_000_000, "h", 99_999, 0))).unwrap();
    for s in 1..=3 {
        first.scalar(&x(s, 1.0));
    }
    first.flush().unwrap();
    let mut rebuilt =
        EventWriter::create(&tb.join(writer::file_name(1_700_000_000, "h", 100_000, 0))).unwrap();
    rebuilt.session_start(0);
    for s in 1..=2 {
        rebuilt.scalar(&x(s, 2.0));
    }
    rebuilt.flush().unwrap();
    // The temporary file alone: nothing for TensorBoard.
    let alone = dir.path().join("alone");
    std::fs::create_dir_all(&alone).unwrap();
    for d in [&alone, tb] {
        let mut tmp = EventWriter::create(&d.join(writer::rebuild_temp_name())).unwrap();
        for s in 1..=5 {
            tmp.scalar(&x(s, 9.0));
        }
        tmp.flush().unwrap();
    }
    assert!(
        tensorboard_scalars(&alone).is_empty(),
        "TensorBoard reads a rebuild's temporary file"
    );
    assert_eq!(
        tensorboard_scalars(tb)["x"],
        vec![(1, 2.0), (2, 2.0)],
        "{:?}",
        std::fs::read_dir(tb)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect::<Vec<_>>()
    );
}

/// A rebuild's temporary files a crash left in `tb/` (this version's name and the
/// `.events.out.tfevents.*.tmp` of earlier ones) are removed when the board opens: TensorBoard
/// sees the log's points once, and nothing stays behind (issue 52: they were never removed).
#[test]
fn a_board_removes_the_temporary_files_a_crashed_rebuild_left() {
    use tboard::writer::{self, EventWriter};
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path();
    let line = r#"{"phase":"rl","episode":0,"loss":0.5,"wall_s":1.0}"#;
    std::fs::write(run.join("metrics.jsonl"), format!("{line}\n")).unwrap();
    let tb = run.join("tb");
    std::fs::create_dir_all(&tb).unwrap();
    let left = [
        writer::rebuild_temp_name(),
        format!(".{}.tmp", writer::new_file_name()),
    ];
    for name in &left {
        let mut w = EventWriter::create(&tb.join(name)).unwrap();
        w.scalar(&tboard::Scalar {
            tag: "losses/td_loss".into(),
            step: 7,
            value: 9.0,
            wall_time: 1.7e9,
        });
        w.flush().unwrap();
    }
    let single = tboard::Mode::SingleProcess {
        updates_per_episode: 20.0,
    };
    drop(tboard::RunBoard::open(run, single).unwrap());
    let names: Vec<String> = std::fs::read_dir(&tb)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| writer::is_event_file(n)),
        "left behind: {names:?}"
    );
    assert_eq!(tensorboard_scalars(&tb)["losses/td_loss"], vec![(1, 0.5)]);
}

#[test]
fn a_distributed_run_and_fsrl_watch_write_the_tags_of_its_logs() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    let out = dir.path().join("dist");
    let mut train = Reaped(
        fsrl()
            .args(["train", "--actors", "2"])
            .args(SHORT)
            .args(["--rl-episodes", "16", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // The launcher names the command that watches the run.
    let (tx, rx) = std::sync::mpsc::channel();
    let stderr = train.0.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(cmd) = line.split("live metrics from another terminal: ").nth(1) {
                let _ = tx.send(cmd.to_string());
            }
            all += &line;
            all.push('\n');
        }
        all
    });
    let cmd = rx
        .recv_timeout(Duration::from_secs(120))
        .expect("the launcher's watch command");
    let words: Vec<&str> = cmd.split_whitespace().collect();
    let arg = |name: &str| words[words.iter().position(|w| *w == name).unwrap() + 1].to_string();
    let watched = dir.path().join("watched");
    let mut watch = Reaped(
        fsrl()
            .args([
                "watch",
                "--connect",
                &arg("--connect"),
                "--run",
                &arg("--run"),
            ])
            .arg("--tensorboard")
            .arg(&watched)
            .args(["--timeout-s", "600"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let deadline = Instant::now() + Duration::from_secs(600);
    let status = loop {
        if let Some(s) = train.0.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline, "the run did not finish");
        std::thread::sleep(Duration::from_millis(100));
    };
    let said = reader.join().unwrap();
    assert!(status.success(), "{said}");
    assert!(
        watch.0.try_wait().unwrap().is_none(),
        "fsrl watch stopped early"
    );
    // Under a loaded machine fsrl watch may still be taking the run's last messages (an
    // actor's few of a short run): give it until every tag is in its files, at most 20 s.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while std::time::Instant::now() < deadline {
        let w = tensorboard_scalars(&watched);
        if watched_tags_present(&w).is_ok() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(500));
    }
    watch.0.kill().unwrap();
    watch.0.wait().unwrap();

    // The run directory's files: the log's tags and values, the learner's live-only ones as
    // the launcher received them.
    let tb = tensorboard_scalars(&out.join("tb"));
    assert_every_tag(&tb);
    assert_steps_rise(&tb);
    let log = lines(&out.join("metrics.jsonl"));
    let want = expected(&log, None);
    assert!(want["validation/success_rate"].len() >= 2, "{want:?}");
    assert!(want.contains_key("perf/episodes_per_s/actor_1"), "{want:?}");
    assert_holds(&tb, &want);
    let live = expected_live(&lines(&out.join("processes.jsonl")));
    assert!(!live.is_empty());
    assert_holds(&tb, &live);
    let alive = &tb["perf/actors_alive"];
    assert!(alive.iter().any(|p| p.1 == 2.0), "{alive:?}");

    // fsrl watch --tensorboard: the same tags from the live metrics alone; validations with the
    // log's values at their steps.
    let w = tensorboard_scalars(&watched);
    assert_steps_rise(&w);
    if let Err(tag) = watched_tags_present(&w) {
        panic!("fsrl watch wrote no {tag}: {:?}", w.keys());
    }
    for tag in ["validation/success_rate", "validation/discomfort"] {
        for (step, value) in &w[tag] {
            let logged = want[tag].iter().find(|p| p.0 == *step);
            let logged = logged.unwrap_or_else(|| panic!("{tag} at {step} is not in the log"));
            assert!(
                (*value - logged.1).abs() <= 1e-6,
                "{tag} at {step}: {value} live, {} in the log",
                logged.1
            );
        }
    }
    let rl: Vec<i64> = w["losses/td_loss"].iter().map(|p| p.0).collect();
    assert!(rl.iter().all(|s| (1..=16).contains(s)), "{rl:?}");
}

/// `fsrl train --no-tensorboard` (what `benches/watch_cost.rs` compares against): no `tb/` in
/// either mode, and the run is otherwise whole (its training log and report).
#[test]
fn no_tensorboard_writes_no_event_files_in_either_mode() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(dir.path());
    for (name, mode) in [
        ("single", &["--single-process"][..]),
        ("dist", &["--actors", "1", "--no-evaluator"][..]),
    ] {
        let out = dir.path().join(name);
        let o = fsrl()
            .arg("train")
            .args(mode)
            .args(SHORT)
            .args(["--rl-episodes", "2", "--no-tensorboard", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(
            out.join("metrics.jsonl").is_file(),
            "{name}: no training log"
        );
        assert!(out.join("report.md").is_file(), "{name}: no report");
        assert!(!out.join("tb").exists(), "{name}: tb/ written");
    }
}

/// Whether `fsrl watch` wrote every tag (the warm start's aside: it may be over before the
/// watcher connects), each actor's per-actor tags counted once an actor has them: an actor
/// whose only metrics came before the watcher subscribed (a short run under load) is in the
/// run's own files, not in the watcher's. `Err`: the first tag missing.
fn watched_tags_present(w: &Points) -> Result<(), String> {
    let has = |t: &str| w.get(t).is_some_and(|p| !p.is_empty());
    for tag in TAGS.iter().filter(|t| !t.starts_with("losses/imitation")) {
        let ok = match tag.rsplit_once("/actor_") {
            Some((stem, _)) => has(tag) || (0..2).any(|i| has(&format!("{stem}/actor_{i}"))),
            None => has(tag),
        };
        if !ok {
            return Err(tag.to_string());
        }
    }
    Ok(())
}
