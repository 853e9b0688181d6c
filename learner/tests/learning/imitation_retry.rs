//! The checkpoint right after imitation on a full disk: the learner process retries it with
//! back-off (each failure counted and logged) instead of dying and redoing the warm start on
//! every restart. A `Probe` fails the first attempts to create the checkpoint file as a full
//! disk would; the process goes on, writes the checkpoint once the disk has room again, and
//! stops cleanly.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use learner::process::{run_with_probe, LearnerExit, LearnerOptions};
use learner::store::{Op, Probe};
use policy::method::{Method, RunSpec, TrainConfig};
use proto::{RunId, SenderId};
use transport::{Transport, TransportConfig, ZenohConfig};

/// Attempts of the post-imitation checkpoint that fail before the disk "has room".
const FULL_DISK_ATTEMPTS: u32 = 2;

#[test]
fn the_checkpoint_after_imitation_is_retried_on_a_full_disk() {
    let port = testkit::free_port();
    let run = RunId::new(format!("ir{}", std::process::id())).unwrap();
    let mut cfg = TransportConfig::new(run.clone(), SenderId::learner());
    cfg.zenoh = ZenohConfig::peer(vec![format!("tcp/127.0.0.1:{port}")], Vec::new());
    let t = Transport::open(cfg).expect("transport");

    let mut train = TrainConfig::default();
    train.imitation.episodes = 2;
    train.imitation.epochs = 1;
    train.rl.episodes = 1_000;
    let spec = RunSpec {
        method: Method::Sarl,
        setting: "env1-invisible".parse().unwrap(),
        sim: sim::SimConfig::default(),
        train,
        seed: 3,
    };
    let dir = tempfile::tempdir().unwrap();
    let opts = LearnerOptions {
        run_dir: dir.path().to_path_buf(),
        run_id: run.to_string(),
        in_flight_per_actor: 2,
        metrics_interval: Duration::from_millis(100),
        linger: Duration::from_millis(100),
    };
    // A full disk for the first attempts at the checkpoint: its file cannot be created.
    let failed = Arc::new(AtomicU32::new(0));
    let seen = Arc::clone(&failed);
    let probe = Probe::new(move |op, path: &Path| {
        let in_checkpoints = path
            .parent()
            .and_then(Path::file_name)
            .is_some_and(|d| d == "checkpoints");
        if op == Op::Created
            && in_checkpoints
            && seen
                .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| {
                    (n < FULL_DISK_ATTEMPTS).then_some(n + 1)
                })
                .is_ok()
        {
            return Err(std::io::Error::new(
                std::io::ErrorKind::StorageFull,
                "no space left on device (injected)",
            ));
        }
        Ok(())
    });
    let checkpoint = dir.path().join("checkpoints").join("latest.ckpt");
    let stop = AtomicBool::new(false);
    let exit = std::thread::scope(|s| {
        let learner = s.spawn(|| run_with_probe(&t, &spec, &opts, &stop, probe));
        // Stop once the checkpoint after imitation is there (or the learner gave up).
        let deadline = Instant::now() + Duration::from_secs(300);
        while !checkpoint.exists() && !learner.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(50));
        }
        stop.store(true, Ordering::SeqCst);
        learner.join().unwrap()
    });
    let exit = exit.expect("a full disk at the checkpoint after imitation is not fatal");
    assert!(matches!(exit, LearnerExit::Stopped), "{exit:?}");
    assert_eq!(failed.load(Ordering::SeqCst), FULL_DISK_ATTEMPTS);
    let loaded = learner::checkpoint::load(&checkpoint).expect("the checkpoint was written");
    assert!(loaded.core.counters().imitation_done);
    assert_eq!(loaded.core.counters().rl_episodes, 0);
}
