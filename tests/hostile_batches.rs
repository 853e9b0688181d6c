//! Hostile but well-formed episodes through the live router (issue 16 items 1–3 and 5, issue
//! 35 item 6): the real `fsrl router` with `deploy/router.json5` (its run id changed as
//! `deploy/README.md` says) and the test CA's users on loopback (`tls/127.0.0.1`, multicast
//! scouting off), the learner and actor 1 started from `deploy/cluster-learner.toml` and
//! `deploy/cluster-actor.toml` (each its own user), and an attacker holding actor 0's real
//! credentials. What those credentials let through the router (actor 0's own transitions key,
//! any header) must neither stop nor poison the learner: episodes of nearly 16 MiB during
//! imitation, a huge episode index, a reward of 1e30, a position of 3e38, headers naming
//! another actor and 4097 fresh ids; the same 4097 ids on their own keys never reach the
//! learner. The learner counts each, actor 1 trains on, and only actor 1's episodes reach the
//! checkpoint. (Without a router, where the learner's own bound on actor ids is what stops
//! 4097 strangers: `tests/distributed.rs`.)

mod hostile_support;
mod multihost_support;
mod net_support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hostile_support::{forge, honest_batch, huge_batch};
use multihost_support::{self as mh, adapt_actor_config, adapt_deploy_config, table};
use net_support::read;
use proto::{keys, Metrics, Role, RunId, SenderId};
use transport::{Subscriber, Transport, TransportConfig, ZenohAuth, ZenohConfig, ZenohTls};

/// Longest wait for the router, a session, a phase of the run.
const PATIENCE: Duration = Duration::from_secs(90);
/// Episodes sent during imitation: of an honest episode's size, and of nearly 16 MiB (more
/// together than a subscriber queues, `transport::SUBSCRIBER_QUEUE_BYTES`).
const IMITATION_SMALL: u64 = 3;
const IMITATION_HUGE: u64 = 6;
/// Fresh actor ids, one more than the learner keeps state for
/// (`proto::control::MAX_CREDIT_GRANTS`).
const FRESH_IDS: u32 = 4097;
/// Long enough that actor 1 is still training after the 8194 forged messages have been sent
/// and counted (with 25, a loaded CI machine once saw the run end first, 2026-12-07).
const RL_EPISODES: u64 = 120;
/// The index every episode sent during imitation carries: should one arrive after the warm
/// start, it is not actor 0's first (0) and is refused as out of order, creating no state.
const IMITATION_EPISODE: u64 = 7;

/// A client of the router at `port` as `user` (its password and the CA from the test CA's
/// files in `secrets`), sending as `sender`.
fn client(secrets: &Path, port: u16, run: &str, sender: SenderId, user: &str) -> Transport {
    let mut cfg = TransportConfig::new(RunId::new(run).unwrap(), sender);
    cfg.zenoh = ZenohConfig::client(format!("tls/127.0.0.1:{port}"));
    cfg.zenoh.tls = Some(ZenohTls {
        root_ca: secrets.join("certs/ca.crt"),
        cert: None,
        key: None,
        verify_name: true,
    });
    cfg.zenoh.auth = Some(ZenohAuth {
        user: user.into(),
        password_file: secrets.join(format!("{user}.password")),
    });
    let start = Instant::now();
    loop {
        match Transport::open(cfg.clone()) {
            Ok(t) => return t,
            Err(e) if start.elapsed() > PATIENCE => panic!("{user}: no session: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

const LEARNER: SenderId = SenderId::new(Role::Learner, 0);

/// The learner's latest metrics, from the monitor's subscription.
struct Watch {
    sub: Subscriber<Metrics>,
    learner: Metrics,
}

impl Watch {
    fn value(&self, key: &str) -> Option<f64> {
        self.learner.values.get(key).copied()
    }

    fn count(&self, key: &str) -> u64 {
        self.value(key).unwrap_or(0.0) as u64
    }

    /// Waits until `pred` holds on the learner's latest metrics.
    fn until(&mut self, what: &str, logs: &dyn Fn() -> String, pred: impl Fn(&Self) -> bool) {
        let deadline = Instant::now() + PATIENCE;
        while !pred(self) {
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}; the learner's metrics: {:?}\n{}",
                self.learner.values,
                logs()
            );
            if let Some(m) = self.sub.recv_timeout(Duration::from_millis(200)).unwrap() {
                if m.header.sender == LEARNER {
                    self.learner = m.body;
                }
            }
        }
    }
}

#[test]
fn hostile_batches_with_an_actors_credentials_neither_stop_nor_poison_the_learner() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = format!("hb{}", std::process::id());
    let mut router = mh::LoopbackRouter::start(d, &run, Path::new(env!("CARGO_BIN_EXE_fsrl")));
    let port = router.port;

    // The deployed configs, pointed at this run and router. A longer warm start than the
    // others' (30 demonstrations, 30 epochs), so that the test can send during it.
    let configure = |t: &mut toml::Table| {
        router.configure(t);
        let r = table(t, &["run"]);
        r.insert("setting".into(), hostile_support::SETTING.into());
        let tr = table(t, &["train"]);
        tr.insert("checkpoint_every_episodes".into(), 0.into());
        let i = table(t, &["train", "imitation"]);
        i.insert("episodes".into(), 30.into());
        i.insert("epochs".into(), 30.into());
        let rl = table(t, &["train", "rl"]);
        rl.insert("episodes".into(), (RL_EPISODES as i64).into());
    };
    let run_dir: PathBuf = d.join("run");
    let learner = adapt_deploy_config("cluster-learner.toml", d, "learner.toml", |t| {
        configure(t);
        let l = table(t, &["learner"]);
        l.insert(
            "run_dir".into(),
            run_dir.to_string_lossy().into_owned().into(),
        );
        l.insert("metrics_interval_ms".into(), 200.into());
        l.insert("linger_ms".into(), 2000.into());
    });
    let actor1 = adapt_actor_config(1, d, "actor-1.toml", configure);
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let logs = || mh::log_tails(d, 30);
    router.spawn(
        "learner",
        &["learner".into(), "--config".into(), s(&learner)],
    );

    let monitor = client(d, port, &run, SenderId::new(Role::Monitor, 0), "monitor");
    let mut w = Watch {
        sub: monitor
            .subscriber(&keys::all_metrics(monitor.run()))
            .unwrap(),
        learner: Metrics::default(),
    };
    // The attacker: actor 0's user and password, whatever headers it writes.
    let evil = client(d, port, &run, SenderId::actor(0), "actor-0");
    let mut pubs = BTreeMap::new();
    let own = evil.publisher(&keys::transitions(evil.run(), 0)).unwrap();
    assert!(
        own.wait_for_subscribers(PATIENCE).unwrap(),
        "actor 0's transitions never matched the learner's subscription\n{}",
        logs()
    );

    // 1. During imitation: refused and counted, not queued; nearly 16 MiB each.
    w.until("the warm start", &logs, |w| {
        w.value("demo_target").is_some() || w.value("imitation_epochs").is_some()
    });
    let small = honest_batch(IMITATION_EPISODE, 11);
    let huge = huge_batch(IMITATION_EPISODE);
    for _ in 0..IMITATION_SMALL {
        forge(&evil, &mut pubs, 0, SenderId::actor(0), &small);
    }
    for _ in 0..IMITATION_HUGE {
        forge(&evil, &mut pubs, 0, SenderId::actor(0), &huge);
    }
    drop(huge);

    // The honest actor joins and trains.
    router.spawn(
        "actor-1",
        &[
            "actor".into(),
            "--config".into(),
            s(&actor1),
            "--id".into(),
            "1".into(),
        ],
    );
    w.until("two episodes of actor 1", &logs, |w| {
        w.count("episodes") >= 2
    });

    // 2. Actor 0's first episode (the one the learner would take) with a reward of 1e30, then
    //    with a position of 3e38: refused whole.
    let good = honest_batch(0, 12);
    let mut rich = good.clone();
    rich.rewards[4] = 1e30; // the first step's total
    forge(&evil, &mut pubs, 0, SenderId::actor(0), &rich);
    let mut far = good.clone();
    far.robot_states[0] = 3e38;
    forge(&evil, &mut pubs, 0, SenderId::actor(0), &far);
    // 3. A huge episode index: out of order, no state.
    let mut late = good.clone();
    late.episode = u64::MAX - 1;
    forge(&evil, &mut pubs, 0, SenderId::actor(0), &late);
    // 4. 4097 fresh ids on their own keys: the router lets none through.
    let mut next = good.clone();
    next.episode = 1;
    for id in 1000..1000 + FRESH_IDS {
        forge(&evil, &mut pubs, id, SenderId::actor(id), &next);
    }
    // 5. Actor 0's key with headers naming actor 1 and the 4097 fresh ids: each rejected by the
    //    key-versus-header check. They come last, so once they are counted, everything before
    //    them reached the learner.
    forge(&evil, &mut pubs, 0, SenderId::actor(1), &good);
    for id in 1000..1000 + FRESH_IDS {
        forge(&evil, &mut pubs, 0, SenderId::actor(id), &next);
    }
    let forged_headers = 1 + u64::from(FRESH_IDS);
    w.until("the forged headers to be counted", &logs, |w| {
        w.count("rejected_messages") >= forged_headers
    });
    // Actor 1 may have two episodes in flight ahead of the hostile ones (its credits); a third
    // one trained means the learner has taken in everything before it.
    let before = w.count("episodes");
    w.until("actor 1's training to go on", &logs, |w| {
        w.count("episodes") >= before + 3
    });
    let counted = |w: &Watch| {
        [
            "rejected_episodes",
            "out_of_order_episodes",
            "rejected_messages",
            "refused_in_imitation",
        ]
        .map(|k| format!("{k} {}", w.count(k)))
        .join(", ")
    };
    println!("after the attacks: {}", counted(&w));
    // The 1e30 reward and the 3e38 position, each refused.
    assert_eq!(
        w.count("rejected_episodes"),
        2,
        "the 1e30 reward and the 3e38 position must each be refused ({})\n{}",
        counted(&w),
        logs()
    );
    // Every forged header, and nothing else (no hostile message turned into another kind).
    assert_eq!(
        w.count("rejected_messages"),
        forged_headers,
        "{}",
        counted(&w)
    );
    // The huge index, plus any episode sent during imitation that arrived after it: none of
    // the 4097 episodes on other actors' keys.
    assert_eq!(
        w.count("refused_in_imitation") + w.count("out_of_order_episodes"),
        IMITATION_SMALL + IMITATION_HUGE + 1,
        "{}\n{}",
        counted(&w),
        logs()
    );
    assert!(
        w.count("refused_in_imitation") >= 1,
        "nothing refused during imitation ({})",
        counted(&w)
    );

    // The run ends normally, with only actor 1's episodes in it.
    let deadline = Instant::now() + PATIENCE;
    let status = loop {
        if let Some((_, status)) = router
            .procs
            .exited()
            .into_iter()
            .find(|(n, _)| n == "learner")
        {
            break status;
        }
        assert!(
            Instant::now() < deadline,
            "the learner did not finish\n{}",
            logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "learner failed\n{}", logs());
    let loaded = learner::checkpoint::load(&run_dir.join("checkpoints/latest.ckpt")).unwrap();
    assert_eq!(loaded.core.counters().rl_episodes, RL_EPISODES);
    assert_eq!(
        loaded.run.accepted_below,
        BTreeMap::from([(1u32, RL_EPISODES)]),
        "only actor 1's episodes, all of them\n{}",
        logs()
    );
    let log = read(&d.join("learner.log"));
    assert!(
        log.contains("during imitation"),
        "the imitation refusal is logged\n{}",
        logs()
    );
    // One source (actor 0's key): its first rejection is logged, the others only counted.
    let lines = log.matches("rejected a message").count();
    assert!(
        (1..=2).contains(&lines),
        "{lines} log lines for {forged_headers} rejected headers"
    );
    router.procs.kill_all();
}
