//! A liveliness flood through the live router: a client with `actor-0`'s real credentials
//! declares more tokens under its own id (`alive/actor/0/<instance>`, which the router allows)
//! than the learner serves actors (4096). The learner counts actor *ids*, keeps at most
//! `transport::MAX_INSTANCES_PER_SENDER` instances of one id (the newest) and counts and logs
//! the rest, so actor 1, started after the flood, is admitted, gets credits and trains.

mod multihost_support;
mod net_support;

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use multihost_support::{self as mh, adapt_actor_config, adapt_deploy_config, table};
use net_support::read;
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

const PATIENCE: Duration = Duration::from_secs(120);
/// More tokens than the learner's cap of actors (`proto::control::MAX_CREDIT_GRANTS`).
const FLOOD: usize = 4200;

/// A raw zenoh client of the router as `user`.
fn session(secrets: &Path, port: u16, user: &str) -> Session {
    net_support::router_session(secrets, port, user, PATIENCE)
}

fn wait_for(what: &str, logs: &dyn Fn() -> String, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + PATIENCE;
    while !cond() {
        assert!(
            Instant::now() < deadline,
            "timed out waiting for {what}\n{}",
            logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_liveliness_flood_from_one_actor_does_not_lock_out_another() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let run = format!("lf{}", std::process::id());
    let mut router = mh::LoopbackRouter::start(d, &run, Path::new(env!("CARGO_BIN_EXE_fsrl")));
    let port = router.port;

    let configure = |t: &mut toml::Table| {
        router.configure(t);
        let i = table(t, &["train", "imitation"]);
        i.insert("episodes".into(), 4.into());
        i.insert("epochs".into(), 1.into());
        let rl = table(t, &["train", "rl"]);
        rl.insert("episodes".into(), 1_000_000.into());
        rl.insert("batches_per_episode".into(), 2.into());
    };
    let run_dir = d.join("run");
    let learner = adapt_deploy_config("cluster-learner.toml", d, "learner.toml", |t| {
        configure(t);
        let l = table(t, &["learner"]);
        l.insert(
            "run_dir".into(),
            run_dir.to_string_lossy().into_owned().into(),
        );
        l.insert("metrics_interval_ms".into(), 200.into());
        l.insert("linger_ms".into(), 500.into());
    });
    let actor1 = adapt_actor_config(1, d, "actor-1.toml", configure);
    let s = |p: &Path| p.to_string_lossy().into_owned();
    router.spawn(
        "learner",
        &["learner".into(), "--config".into(), s(&learner)],
    );
    let logs = || mh::log_tails(d, 30);
    let learner_log = || read(&d.join("learner.log"));
    wait_for("the learner's warm start", &logs, || {
        learner_log().contains("imitation done")
    });

    // The flood: actor 0's credentials, tokens under its own id, all accepted by the router.
    let monitor = session(d, port, "monitor");
    let seen = Arc::new(AtomicUsize::new(0));
    let counted = Arc::clone(&seen);
    let _watch = monitor
        .liveliness()
        .declare_subscriber(format!("fsrl/{run}/alive/actor/0/*"))
        .history(true)
        .callback(move |sample| {
            if sample.kind() == SampleKind::Put {
                counted.fetch_add(1, Ordering::SeqCst);
            }
        })
        .wait()
        .unwrap();
    let flooder = session(d, port, "actor-0");
    let tokens: Vec<_> = (0..FLOOD)
        .map(|i| {
            flooder
                .liveliness()
                .declare_token(format!("fsrl/{run}/alive/actor/0/{:016x}", 0x1000 + i))
                .wait()
                .unwrap()
        })
        .collect();
    wait_for("the flood to pass the router", &logs, || {
        seen.load(Ordering::SeqCst) >= FLOOD
    });

    // Actor 1 joins after the flood and trains.
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
    let rl_lines = || {
        read(&run_dir.join("metrics.jsonl"))
            .lines()
            .filter(|l| l.contains("\"phase\":\"rl\""))
            .count()
    };
    wait_for("actor 1's episodes to be trained on", &logs, || {
        rl_lines() >= 3
    });
    let log = learner_log();
    assert!(
        log.contains("actor joined") && log.contains("actor-1#"),
        "{}",
        logs()
    );
    // The flood was refused, counted and logged (at powers of two of the count).
    assert!(
        log.contains("liveliness tokens not tracked"),
        "no refusal logged\n{}",
        logs()
    );
    drop(tokens);
    router.procs.kill_all();
}
