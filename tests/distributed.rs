//! Multi-process tests: the real `fsrl` binary as learner, actors and evaluator, over zenoh and
//! over iceoryx2. Readiness comes from liveliness and live metrics (a monitor transport in the
//! test), never from sleeping.

mod hostile_support;
mod net_support;
mod shm_support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hostile_support::{forge, honest_batch};
use net_support::{ephemeral_low, free_port, Children};
use proto::{keys, Metrics, Role, RunId, SenderId};
use shm_support::ShmSnapshot;
use transport::{DataPlane, Subscriber, Transport, TransportConfig, ZenohConfig};

const TIMEOUT: Duration = Duration::from_secs(180);

struct Run {
    id: String,
    dir: tempfile::TempDir,
    port: u16,
    plane: &'static str,
    extra_config: String,
}

impl Run {
    fn new(tag: &str, plane: &'static str, extra_config: &str) -> Self {
        let id = format!("t{}-{tag}-{}", std::process::id(), free_port());
        Self {
            id,
            dir: tempfile::tempdir().unwrap(),
            port: free_port(),
            plane,
            extra_config: extra_config.to_string(),
        }
    }

    fn endpoint(&self) -> String {
        format!("tcp/127.0.0.1:{}", self.port)
    }

    fn config(&self) -> PathBuf {
        let p = self.dir.path().join("run.toml");
        if !p.exists() {
            std::fs::write(
                &p,
                format!(
                    "[run]\nid = \"{}\"\nmethod = \"sarl\"\nsetting = \"env2-visible\"\n[train.imitation]\nepisodes = 6\nepochs = 1\n[learner]\nmetrics_interval_ms = 200\nlinger_ms = 2000\n{}",
                    self.id, self.extra_config
                ),
            )
            .unwrap();
        }
        p
    }

    fn spawn(&self, role: &str, extra: &[&str]) -> Child {
        let log = std::fs::File::create(
            self.dir
                .path()
                .join(format!("{role}-{}.log", extra.join("_").replace('/', ""))),
        )
        .unwrap();
        let mut c = Command::new(env!("CARGO_BIN_EXE_fsrl"));
        c.arg(role)
            .arg("--config")
            .arg(self.config())
            .args(["--data-plane", self.plane, "--run-dir"])
            .arg(self.dir.path().join("run"));
        if role == "learner" {
            c.args(["--listen", &self.endpoint()]);
        } else {
            c.args(["--listen", "tcp/127.0.0.1:0", "--connect", &self.endpoint()]);
        }
        c.args(extra)
            .stdin(Stdio::null())
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap()
    }

    fn monitor(&self, index: u32) -> Transport {
        let mut cfg = TransportConfig::new(
            RunId::new(self.id.clone()).unwrap(),
            SenderId::new(Role::Monitor, index),
        );
        cfg.zenoh = ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![self.endpoint()]);
        cfg.data_plane = if self.plane == "iceoryx2" {
            DataPlane::Iceoryx2
        } else {
            DataPlane::Zenoh
        };
        Transport::open(cfg).unwrap()
    }

    fn logs(&self) -> String {
        let mut s = String::new();
        for e in std::fs::read_dir(self.dir.path()).unwrap().flatten() {
            if e.path().extension().is_some_and(|x| x == "log") {
                s += &format!(
                    "--- {}\n{}\n",
                    e.path().display(),
                    std::fs::read_to_string(e.path()).unwrap_or_default()
                );
            }
        }
        s
    }

    fn run_dir(&self) -> PathBuf {
        self.dir.path().join("run")
    }
}

/// The latest metrics of each sender, updated from the subscription.
struct Watch {
    sub: Subscriber<Metrics>,
    latest: BTreeMap<SenderId, Metrics>,
}

impl Watch {
    fn new(t: &Transport) -> Self {
        Self {
            sub: t.subscriber(&keys::all_metrics(t.run())).unwrap(),
            latest: BTreeMap::new(),
        }
    }

    fn value(&self, sender: SenderId, key: &str) -> Option<f64> {
        self.latest.get(&sender)?.values.get(key).copied()
    }

    /// Waits until `pred` holds on the latest metrics.
    fn until(&mut self, what: &str, run: &Run, mut pred: impl FnMut(&Self) -> bool) {
        let deadline = Instant::now() + TIMEOUT;
        while !pred(self) {
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}\n{}",
                run.logs()
            );
            if let Some(m) = self.sub.recv_timeout(Duration::from_millis(200)).unwrap() {
                self.latest.insert(m.header.sender, m.body);
            }
        }
    }
}

const LEARNER: SenderId = SenderId::new(Role::Learner, 0);

fn wait_exit(c: &mut Child, what: &str, run: &Run) -> std::process::ExitStatus {
    let deadline = Instant::now() + TIMEOUT;
    loop {
        if let Some(s) = c.try_wait().unwrap() {
            return s;
        }
        assert!(
            Instant::now() < deadline,
            "{what} did not exit\n{}",
            run.logs()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Returns the run's id.
fn two_process_run(plane: &'static str) -> String {
    let run = Run::new("two", plane, "");
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "4"])]);
    // Watch the weights before the actor starts: its four RL episodes at 20 updates each take
    // well under a second, and a monitor that joined after them would see only the last version.
    let mon = run.monitor(0);
    let weights = mon.latest_subscriber(&keys::weights(mon.run())).unwrap();
    let alive = mon.watch_alive().unwrap();
    let deadline = Instant::now() + TIMEOUT;
    loop {
        assert!(Instant::now() < deadline, "no learner\n{}", run.logs());
        if let Some(transport::AliveEvent::Joined(m)) =
            alive.recv_timeout(Duration::from_millis(200)).unwrap()
        {
            if m.sender.role == Role::Learner {
                break;
            }
        }
    }
    procs
        .0
        .push(run.spawn("actor", &["--rl-episodes", "4", "--id", "0"]));
    let mut versions = std::collections::BTreeSet::new();
    let deadline = Instant::now() + TIMEOUT;
    while versions.len() < 2 {
        assert!(
            Instant::now() < deadline,
            "fewer than 2 weight versions seen\n{}",
            run.logs()
        );
        if let Some(w) = weights.next(Duration::from_millis(200)).unwrap() {
            assert_eq!(w.body.version, w.header.policy_version);
            assert_eq!(w.body.params.len(), 96_502);
            versions.insert(w.body.version);
        }
    }
    let status = wait_exit(&mut procs.0[0], "the learner", &run);
    assert!(status.success(), "learner failed\n{}", run.logs());
    let status = wait_exit(&mut procs.0[1], "the actor", &run);
    assert!(status.success(), "actor failed\n{}", run.logs());
    let loaded = learner::checkpoint::load(&run.run_dir().join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(loaded.core.counters().rl_episodes, 4);
    assert_eq!(loaded.run.accepted_below.get(&0).copied(), Some(4));
    println!("{plane}: weight versions seen {versions:?}");
    run.id.clone()
}

#[test]
fn learner_and_actor_train_over_zenoh() {
    two_process_run("zenoh");
}

#[test]
fn learner_and_actor_train_over_iceoryx2_and_clean_up_shared_memory() {
    let before = ShmSnapshot::take();
    let id = two_process_run("iceoryx2");
    // This run's segments only: other tests of this binary run their own at the same time.
    let leaked = before.new_since(|e| e.contains(&format!("fsrl_{id}_")));
    assert!(leaked.is_empty(), "shared memory left behind: {leaked:?}");
}

#[test]
fn a_killed_actor_is_noticed_and_a_new_one_joins() {
    let run = Run::new("kill-actor", "zenoh", "");
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "100000"])]);
    procs.0.push(run.spawn("actor", &["--id", "0"]));
    let mon = run.monitor(1);
    let mut w = Watch::new(&mon);
    w.until("two episodes from actor 0", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= 2.0
    });
    procs.0[1].kill().unwrap();
    procs.0[1].wait().unwrap();
    w.until("the learner to see the actor leave", &run, |w| {
        w.value(LEARNER, "actors_alive") == Some(0.0)
    });
    let before = w.value(LEARNER, "episodes").unwrap();
    procs.0.push(run.spawn("actor", &["--id", "1"]));
    w.until("episodes from the new actor", &run, |w| {
        w.value(LEARNER, "actors_alive") == Some(1.0)
            && w.value(LEARNER, "episodes").unwrap_or(0.0) >= before + 2.0
    });
    assert!(
        procs.0[0].try_wait().unwrap().is_none(),
        "the learner must go on\n{}",
        run.logs()
    );
}

#[test]
fn a_killed_learner_restarts_from_its_checkpoint_and_loses_no_acknowledged_episode() {
    // No periodic checkpoint: every RL episode lives only in the write-ahead log.
    let run = Run::new(
        "kill-learner",
        "zenoh",
        "[train]\ncheckpoint_every_episodes = 0\n",
    );
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "100000"])]);
    procs.0.push(run.spawn("actor", &["--id", "0"]));
    let mon = run.monitor(2);
    let mut w = Watch::new(&mon);
    let actor = SenderId::new(Role::Actor, 0);
    w.until("three acknowledged episodes", &run, |w| {
        w.value(actor, "episodes_acked").unwrap_or(0.0) >= 3.0
    });
    procs.0[0].kill().unwrap();
    procs.0[0].wait().unwrap();
    // The actor's count is final once it sees no learner: wait for two fresh reports that agree.
    let mut last = -1.0;
    w.until("the actor's final acknowledged count", &run, |w| {
        let v = w.value(actor, "episodes_acked").unwrap_or(-2.0);
        let stable = v == last;
        last = v;
        stable
    });
    let acked = last;
    w.latest.remove(&LEARNER);
    procs.0[0] = run.spawn("learner", &["--rl-episodes", "100000"]);
    w.until("the restarted learner's first report", &run, |w| {
        w.value(LEARNER, "episodes").is_some()
    });
    let restored = w.value(LEARNER, "episodes").unwrap();
    println!("acknowledged before the kill: {acked}; episodes after restart: {restored}");
    assert!(
        restored >= acked,
        "acknowledged episodes lost: {acked} acked, {restored} restored\n{}",
        run.logs()
    );
    // And the actor resumes feeding the new learner.
    w.until("training to go on", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= restored + 2.0
    });
}

#[test]
fn garbage_on_the_transitions_key_is_rejected_and_counted() {
    let run = Run::new("garbage", "zenoh", "");
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "100000"])]);
    procs.0.push(run.spawn("actor", &["--id", "0"]));
    let mon = run.monitor(3);
    let mut w = Watch::new(&mon);
    w.until("training", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= 1.0
    });
    let evil = mon.publisher(&keys::transitions(mon.run(), 7)).unwrap();
    for k in 0..20u8 {
        evil.publish_raw(vec![0x93, k, 0xff, 0x00, 0x12, k.wrapping_mul(31)])
            .unwrap();
    }
    let before = w.value(LEARNER, "episodes").unwrap();
    w.until("the garbage to be counted", &run, |w| {
        w.value(LEARNER, "rejected_messages").unwrap_or(0.0) >= 1.0
    });
    w.until("training to go on", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= before + 2.0
    });
    assert!(procs.0[0].try_wait().unwrap().is_none());
}

#[test]
fn the_evaluator_reports_a_checkpoint_on_all_six_settings() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args([
            "train",
            "--single-process",
            "--method",
            "fsrl",
            "--il-episodes",
            "5",
            "--il-epochs",
            "1",
        ])
        .args(["--rl-episodes", "1", "--eval-episodes", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval = dir.path().join("eval");
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(["evaluator", "--episodes", "3", "--checkpoint"])
        .arg(out.join("checkpoints/latest.ckpt"))
        .arg("--out-dir")
        .arg(&eval)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval.join("report.json")).unwrap()).unwrap();
    let names: Vec<&str> = r["settings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["setting"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "env1-invisible",
            "env2-invisible",
            "env3-invisible",
            "env1-visible",
            "env2-visible",
            "env3-visible"
        ]
    );
    for s in r["settings"].as_array().unwrap() {
        assert_eq!(s["episodes"], 3);
    }
    let md = std::fs::read_to_string(eval.join("report.md")).unwrap();
    assert!(md.contains("| average visible |"), "{md}");
    let _ = Path::new(&eval);
}

#[test]
fn live_metrics_are_readable_by_fsrl_watch_and_by_python() {
    let run = Run::new("watch", "zenoh", "");
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "100000"])]);
    procs.0.push(run.spawn("actor", &["--id", "0"]));
    let mon = run.monitor(4);
    let mut w = Watch::new(&mon);
    w.until("training", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= 1.0
    });

    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args([
            "watch",
            "--connect",
            &run.endpoint(),
            "--run",
            &run.id,
            "--count",
            "3",
            "--timeout-s",
            "60",
        ])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        out.lines().count() >= 3 && out.contains("episodes="),
        "{out}"
    );

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/watch_metrics.py");
    let o = Command::new("python3")
        .arg(&script)
        .args([
            "--connect",
            &run.endpoint(),
            "--run",
            &run.id,
            "--count",
            "4",
            "--timeout",
            "60",
        ])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success(),
        "python watcher failed ({}):\n{out}\n{err}",
        o.status
    );
    let learner_line = out
        .lines()
        .find(|l| l.starts_with("learner-0"))
        .unwrap_or_else(|| panic!("no learner metrics in\n{out}"));
    for field in [
        "episodes=",
        "loss=",
        "success_rate=",
        "policy_lag_mean=",
        "replay_size=",
        "rejected_messages=",
        "actors_alive=",
    ] {
        assert!(
            learner_line.contains(field),
            "missing {field} in {learner_line}"
        );
    }
}

#[test]
fn one_command_local_training_runs_every_process_and_leaves_a_run_directory() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("local-run");
    let before = ShmSnapshot::take();
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args([
            "train",
            "--method",
            "sarl",
            "--setting",
            "env3-visible",
            "--actors",
            "2",
        ])
        .args([
            "--il-episodes",
            "6",
            "--il-epochs",
            "1",
            "--rl-episodes",
            "4",
            "--eval-episodes",
            "2",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("fsrl watch --connect"), "{stderr}");
    for f in [
        "config.toml",
        "checkpoints/latest.ckpt",
        "metrics.jsonl",
        "report.md",
        "report.json",
        "run.json",
        "processes.jsonl",
        "logs/learner.log",
        "logs/actor-1.log",
        "logs/evaluator.log",
    ] {
        assert!(out.join(f).is_file(), "missing {f}");
    }
    // The final evaluation is the one of `--single-process`: the run's policy (here, by the
    // default `low-disc` rule, one of the evaluator's snapshots) on its own setting.
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let settings = r["settings"].as_array().unwrap();
    assert_eq!(settings.len(), 1, "{r}");
    assert_eq!(settings[0]["setting"], "env3-visible");
    assert_eq!(settings[0]["episodes"], 2);
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
    assert_eq!(run["mode"], "distributed", "{run}");
    assert_eq!(run["actors"], 2, "{run}");
    let loaded = learner::checkpoint::load(&out.join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(loaded.core.counters().rl_episodes, 4);
    let metrics = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    // The learner's training log: the imitation epoch and one line per RL episode, in order.
    let rl = episodes_of(&metrics, "rl");
    assert_eq!(rl, [0, 1, 2, 3], "{metrics}");
    assert!(metrics.contains("\"phase\":\"imitation\""), "{metrics}");
    // The learning curve: the evaluator scored the final weights on the validation seeds of the
    // run's setting, and the point reached metrics.jsonl.
    let validation: Vec<serde_json::Value> = metrics
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["phase"] == "validation")
        .collect();
    let last = validation
        .last()
        .expect("a validation line in metrics.jsonl");
    assert_eq!(last["episode"], 4, "{last}");
    assert_eq!(last["episodes"], 100, "{last}");
    let rates: f64 = ["success_rate", "collision_rate", "timeout_rate"]
        .iter()
        .map(|k| last[k].as_f64().unwrap())
        .sum();
    assert!((rates - 1.0).abs() < 1e-9, "{last}");
    // This run's segments only (its run id is the run directory's name): other tests of this
    // binary run their own at the same time.
    let leaked = before.new_since(|e| e.contains("fsrl_local-run_"));
    assert!(leaked.is_empty(), "shared memory left behind: {leaked:?}");
    // The same command again refuses to overwrite the run.
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args([
            "train",
            "--method",
            "sarl",
            "--setting",
            "env3-visible",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume"));
}

/// Hostile but well-formed input from a client on the learner's own endpoint, no router in
/// between (a local run; issue 16, items 1–3 and 5): an episode sent during imitation, another
/// actor's id with a huge episode index, a reward of 1e30, a position of 3e38, a header that
/// contradicts its key, and 4097 fresh actor ids on their own keys. The learner stays up and
/// counts each, the honest actor keeps progressing, and nothing poisoned reaches the
/// checkpoint. The same attacks with an actor's credentials through the live router, where
/// the router keeps other actors' keys out: `tests/hostile_batches.rs`.
#[test]
fn hostile_but_well_formed_episodes_neither_stop_nor_poison_the_learner() {
    let run = Run::new(
        "hostile",
        "zenoh",
        "[train]\ncheckpoint_every_episodes = 0\n",
    );
    // A longer imitation, so the test can send during it.
    std::fs::write(
        run.config(),
        std::fs::read_to_string(run.config())
            .unwrap()
            .replace("episodes = 6\nepochs = 1", "episodes = 30\nepochs = 30"),
    )
    .unwrap();
    let mut procs = Children(vec![run.spawn("learner", &["--rl-episodes", "25"])]);
    let mon = run.monitor(4);
    let mut w = Watch::new(&mon);
    let evil = {
        let mut cfg = TransportConfig::new(
            RunId::new(run.id.clone()).unwrap(),
            SenderId::new(Role::Actor, 9),
        );
        cfg.zenoh = ZenohConfig::peer(vec!["tcp/127.0.0.1:0".into()], vec![run.endpoint()]);
        Transport::open(cfg).unwrap()
    };
    let mut pubs = BTreeMap::new();
    let good = honest_batch(0, 11);
    // 1. During imitation: refused and counted, not queued.
    w.until("imitation to start", &run, |w| {
        w.value(LEARNER, "imitation_epochs").is_some() || w.value(LEARNER, "demo_target").is_some()
    });
    for _ in 0..3 {
        forge(&evil, &mut pubs, 9, SenderId::actor(9), &good);
    }
    procs.0.push(run.spawn("actor", &["--id", "0"]));
    w.until("two honest episodes", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= 2.0
    });
    // 2. Actor 0's id with a huge episode index (on actor 0's own key).
    let mut huge = honest_batch(u64::MAX - 1, 12);
    huge.episode = u64::MAX - 1;
    forge(&evil, &mut pubs, 0, SenderId::actor(0), &huge);
    // 3. A reward of 1e30 and a position of 3e38, as actor 9's next episode.
    let mut rich = good.clone();
    rich.rewards[4] = 1e30; // the first step's total
    forge(&evil, &mut pubs, 9, SenderId::actor(9), &rich);
    let mut far = good.clone();
    far.robot_states[0] = 3e38;
    forge(&evil, &mut pubs, 9, SenderId::actor(9), &far);
    // 4. A header naming actor 0 on actor 9's key.
    forge(&evil, &mut pubs, 9, SenderId::actor(0), &good);
    // 5. 4097 fresh ids, each with an episode the learner does not expect from a newcomer.
    let mut late = good.clone();
    late.episode = 1;
    for id in 1000..1000 + 4097 {
        forge(&evil, &mut pubs, id, SenderId::actor(id), &late);
    }
    let before = w.value(LEARNER, "episodes").unwrap();
    w.until("the hostile input to be counted", &run, |w| {
        w.value(LEARNER, "out_of_order_episodes").unwrap_or(0.0) >= 4098.0
            && w.value(LEARNER, "rejected_episodes").unwrap_or(0.0) >= 2.0
            && w.value(LEARNER, "rejected_messages").unwrap_or(0.0) >= 1.0
    });
    w.until("honest training to go on", &run, |w| {
        w.value(LEARNER, "episodes").unwrap_or(0.0) >= before + 2.0
    });
    let status = wait_exit(&mut procs.0[0], "the learner", &run);
    assert!(status.success(), "learner failed\n{}", run.logs());
    let loaded = learner::checkpoint::load(&run.run_dir().join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(loaded.core.counters().rl_episodes, 25);
    // Only the honest actor has state, and its count is its real one.
    assert_eq!(
        loaded.run.accepted_below,
        BTreeMap::from([(0u32, 25u64)]),
        "{}",
        run.logs()
    );
    let log = run.logs();
    assert!(
        log.contains("during imitation"),
        "the imitation refusal is logged\n{log}"
    );
    // Rate-limited: 4097 refusals make a handful of lines, not thousands.
    let lines = log.matches("while 0 is due").count();
    assert!(lines <= 14, "{lines} log lines for 4097 refusals");
}

/// Issue 44: the learner drains liveliness during imitation too. A client declares more
/// liveliness tokens than the learner's liveliness queue holds (1024), then sends episodes over
/// the same link, all during the warm start: the learner tracks every token then (its
/// `actors_alive`) and still reads the episodes behind them (and refuses them, as it should
/// then). Before, nothing read liveliness until training started: the queue filled and its
/// filler (a zenoh thread) waited; during imitation the learner saw none of the 3000.
#[test]
fn a_liveliness_flood_during_imitation_does_not_hold_the_learners_link() {
    let run = Run::new("aliveflood", "zenoh", "");
    // A long imitation, so the flood and what follows it happen in it.
    std::fs::write(
        run.config(),
        std::fs::read_to_string(run.config())
            .unwrap()
            .replace("episodes = 6\nepochs = 1", "episodes = 30\nepochs = 200"),
    )
    .unwrap();
    let _procs = Children(vec![run.spawn("learner", &["--rl-episodes", "5"])]);
    let mon = run.monitor(4);
    let mut w = Watch::new(&mon);
    w.until("imitation to start", &run, |w| {
        w.value(LEARNER, "imitation_epochs").is_some() || w.value(LEARNER, "demo_target").is_some()
    });
    let q = |s: &str| serde_json::to_string(s).unwrap();
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", q("client")),
        ("connect/endpoints", format!("[{}]", q(&run.endpoint()))),
        ("scouting/multicast/enabled", "false".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    let session = zenoh::Wait::wait(zenoh::open(c)).unwrap();
    let id = RunId::new(run.id.clone()).unwrap();
    const TOKENS: u32 = 3000;
    let _tokens: Vec<_> = (0..TOKENS)
        .map(|k| {
            let member = keys::Member {
                sender: SenderId::actor(10_000 + k),
                instance: 1,
            };
            zenoh::Wait::wait(session.liveliness().declare_token(keys::alive(&id, member))).unwrap()
        })
        .collect();
    let header = proto::Header::new::<proto::TransitionBatch>(id.clone(), SenderId::actor(9), 0, 1);
    let bytes = proto::encode(&header, &honest_batch(0, 11)).unwrap();
    const SENT: f64 = 3.0;
    for _ in 0..SENT as u32 {
        let key = keys::transitions(&id, 9);
        zenoh::Wait::wait(session.put(key.key_expr(), bytes.clone())).unwrap();
    }
    w.until(
        "the episodes behind the tokens, or the end of imitation",
        &run,
        |w| {
            w.value(LEARNER, "refused_in_imitation").unwrap_or(0.0) >= SENT
                || w.value(LEARNER, "imitation_done").unwrap_or(0.0) > 0.5
        },
    );
    assert!(
        w.value(LEARNER, "imitation_done").unwrap_or(0.0) < 0.5
            && w.value(LEARNER, "actors_alive").unwrap_or(0.0) >= f64::from(TOKENS),
        "during imitation the learner saw {:?} of {SENT} episodes and {:?} of {TOKENS} actors\n{}",
        w.value(LEARNER, "refused_in_imitation"),
        w.value(LEARNER, "actors_alive"),
        run.logs()
    );
}

/// Fair intake (Experiment 16): iceoryx2 serves its publishers' queues in a fixed order, so a
/// learner that took one message per round of updates handed over actor 0's next episode every
/// time and starved actor 1 until its publications timed out. The learner now takes in everything
/// pending before each round and trains in arrival order: over 40 RL episodes at the default 20
/// updates each (the learner, not the actors, sets the pace) both actors get a fair share.
#[test]
fn two_actors_share_the_learner_fairly_over_iceoryx2() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fair");
    let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
        .args(["train", "--method", "sarl", "--setting", "env1-invisible"])
        .args(["--actors", "2", "--transport", "iceoryx2", "--no-evaluator"])
        .args([
            "--il-episodes",
            "6",
            "--il-epochs",
            "1",
            "--rl-episodes",
            "40",
        ])
        .args(["--eval-episodes", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let loaded = learner::checkpoint::load(&out.join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(loaded.core.counters().rl_episodes, 40);
    let accepted = |k: u32| loaded.run.accepted_below.get(&k).copied().unwrap_or(0);
    let (a0, a1) = (accepted(0), accepted(1));
    assert_eq!(a0 + a1, 40, "{:?}", loaded.run.accepted_below);
    assert!(
        a0.min(a1) >= 10,
        "one actor was starved: actor 0 {a0}, actor 1 {a1} of 40 episodes"
    );
}

/// The adaptive mode (`train.rl.replay_ratio`), as processes: the learner trains in rounds not
/// tied to episodes, and the realised updates per accepted episode stay within the bounds,
/// whatever the speed of actors and learner (which of the two bounds a run sits at depends on
/// them): equal bounds hold it exactly, and a `min` above `batches_per_episode` makes the
/// learner train between episodes (with the fixed schedule it would do 2 per episode).
#[test]
fn the_adaptive_mode_keeps_its_replay_ratio_within_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let ratio = |name: &str, min: f64, max: f64, evaluator: bool, extra: &[&str]| {
        let out = dir.path().join(name);
        let config = dir.path().join(format!("{name}.toml"));
        std::fs::write(
            &config,
            format!(
                "[train]\nvalidation_every_episodes = 10\nvalidation_episodes = 3\n\
                 [train.imitation]\nepisodes = 6\nepochs = 1\n[train.rl]\nepisodes = 40\n\
                 batches_per_episode = 2\nreplay_ratio = {{ min = {min}, max = {max} }}\n"
            ),
        )
        .unwrap();
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_fsrl"));
        cmd.args(["train", "--method", "sarl", "--setting", "env1-invisible"])
            .args(["--actors", "2", "--transport", "iceoryx2"])
            .args(["--eval-episodes", "2", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&out);
        if !evaluator {
            cmd.arg("--no-evaluator");
        }
        cmd.args(extra);
        let o = cmd.output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{stderr}");
        let loaded = learner::checkpoint::load(&out.join("checkpoints/latest.ckpt")).unwrap();
        assert_eq!(loaded.core.counters().rl_episodes, 40);
        let run: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
        let realised = run["learner_updates_per_episode"].as_f64().unwrap();
        if extra.is_empty() {
            assert!(
                realised >= min - 1e-9 && realised <= max + 1.0 / 40.0,
                "{name}: {realised} updates per episode, bounds [{min}, {max}]"
            );
            assert_eq!(run["replay_ratio"]["min"], min, "{run}");
        }
        (realised, out)
    };
    let (tight, out) = ratio("tight", 3.0, 3.0, true, &[]);
    assert!((tight - 3.0).abs() < 1e-9, "{tight}");
    // A weights version is a round of updates here, not an episode: the evaluator labels its
    // validations and snapshots with the RL episodes the weights say they were trained on.
    let metrics = std::fs::read_to_string(out.join("metrics.jsonl")).unwrap();
    let validated = episodes_of(&metrics, "validation");
    assert!(!validated.is_empty(), "{metrics}");
    assert!(
        validated.iter().all(|&e| e <= 40) && validated.contains(&40),
        "validations labelled {validated:?} in a run of 40 RL episodes"
    );
    ratio("wide", 5.0, 400.0, false, &[]);
    // `--replay-ratio fixed` overrides the file: the fixed schedule's 2 updates per episode.
    let (fixed, out) = ratio("fixed", 3.0, 3.0, false, &["--replay-ratio", "fixed"]);
    assert!((fixed - 2.0).abs() < 1e-9, "{fixed}");
    let run = std::fs::read_to_string(out.join("run.json")).unwrap();
    assert!(run.contains("\"replay_ratio\": \"fixed 2\""), "{run}");

    // The lockstep mode has no adaptive schedule: refused before anything is written, whether
    // the file or the flag asks for it.
    let config = dir.path().join("tight.toml").to_string_lossy().into_owned();
    let out = dir.path().join("single");
    for asks in [["--config", config.as_str()], ["--replay-ratio", "4,20"]] {
        let o = Command::new(env!("CARGO_BIN_EXE_fsrl"))
            .args(["train", "--single-process"])
            .args(asks)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{asks:?}");
        assert!(
            stderr.contains("needs a distributed run"),
            "{asks:?}: {stderr}"
        );
        assert!(!out.exists(), "{asks:?}");
    }
}

/// The `episode` of every line of `phase` in a run's `metrics.jsonl`, in order.
fn episodes_of(metrics: &str, phase: &str) -> Vec<u64> {
    metrics
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["phase"] == phase)
        .map(|v| v["episode"].as_u64().unwrap())
        .collect()
}

/// The ports the tests give their processes lie below the ephemeral range, where no outgoing
/// connection's source port can take them between the check and the process's bind, and are
/// never handed out twice (a CI run lost a learner's `--listen` port to such a race).
#[test]
fn test_ports_are_below_the_ephemeral_range_and_distinct() {
    let ports: Vec<u16> = (0..200).map(|_| free_port()).collect();
    let low = ephemeral_low();
    assert!(
        ports.iter().all(|&p| u32::from(p) < low),
        "a port at or above {low}: {ports:?}"
    );
    let distinct: std::collections::BTreeSet<u16> = ports.iter().copied().collect();
    assert_eq!(distinct.len(), ports.len(), "a port handed out twice");
}
