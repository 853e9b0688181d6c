//! The learner process's phases, driven as a real process (in a thread, over zenoh on
//! 127.0.0.1) by a stand-in actor: the adaptive schedule's top-up and a stop during it, the
//! final figures of the run's record, and the linger's liveliness tracking.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use policy::method::{ReplayRatio, RunSpec, TrainConfig};
use proto::{keys, Member, RunId, RunPhase, SenderId};
use transport::{AliveEvent, Heartbeat};

use super::{restore, training, Learner, LearnerExit, LearnerOptions, MAX_ACTORS};
use crate::store::{Op, Probe};

#[path = "../../tests/support/run.rs"]
mod run;
use run::{episode, transport};

const PATIENCE: Duration = Duration::from_secs(120);

/// RL episodes of the adaptive runs below.
const EPISODES: u64 = 4;

/// Updates per episode of the adaptive runs below (`min = max`).
const RATIO: f64 = 3.0;

/// A short adaptive run's spec: `RATIO` updates per episode in rounds of at most 2, so the
/// last episode taken is owed updates after it (the top-up).
fn adaptive_spec() -> RunSpec {
    let mut train = TrainConfig::default();
    train.imitation.episodes = 2;
    train.imitation.epochs = 1;
    train.rl.episodes = EPISODES;
    train.rl.batches_per_episode = 2;
    train.rl.replay_ratio = Some(ReplayRatio {
        min: RATIO,
        max: RATIO,
    });
    run::spec(train)
}

fn options(dir: &Path, run: &RunId, linger: Duration) -> LearnerOptions {
    LearnerOptions {
        run_dir: dir.to_path_buf(),
        run_id: run.to_string(),
        in_flight_per_actor: EPISODES,
        metrics_interval: Duration::from_millis(100),
        linger,
    }
}

/// The adaptive learner as a process (in a thread) in `dir`, fed every episode at once by a
/// stand-in actor once it trains. With `stop_at_last`, `stop` is set while the learner stores
/// the run's last episode (its write to the write-ahead log): after it, only the top-up is
/// left, so the stop comes during the top-up, every time.
fn adaptive_run(dir: &Path, name: &str, stop_at_last: bool) -> LearnerExit {
    let port = testkit::free_port();
    let run = RunId::new(format!("{name}{}", std::process::id())).unwrap();
    let t = transport(&run, SenderId::learner(), port, true);
    let spec = adaptive_spec();
    let opts = options(dir, &run, Duration::from_millis(300));
    let stop = Arc::new(AtomicBool::new(false));
    let (stopper, wal) = (Arc::clone(&stop), crate::store::wal_path(dir));
    let appended = AtomicU64::new(0);
    let probe = Probe::new(move |op, path: &Path| {
        if stop_at_last
            && op == Op::Written
            && path == wal
            && appended.fetch_add(1, Ordering::SeqCst) + 1 == EPISODES
        {
            stopper.store(true, Ordering::SeqCst);
        }
        Ok(())
    });
    let exit = std::thread::scope(|s| {
        let learner = s.spawn(|| super::run_with_probe(&t, &spec, &opts, &stop, probe));
        let actor = transport(&run, SenderId::actor(0), port, false);
        let _alive = actor.declare_alive().unwrap();
        let out = actor.publisher(&keys::transitions(&run, 0)).unwrap();
        let controls = actor.latest_subscriber(&keys::control(&run)).unwrap();
        let deadline = Instant::now() + PATIENCE;
        let mut sent = false;
        while !learner.is_finished() {
            assert!(Instant::now() < deadline, "the run did not end");
            let Some(c) = controls.next(Duration::from_millis(5)).unwrap() else {
                continue;
            };
            if c.body.phase == RunPhase::Training && !sent {
                for k in 0..EPISODES {
                    out.publish(0, &episode(&spec, k)).unwrap();
                }
                sent = true;
            }
        }
        learner.join().unwrap()
    });
    exit.expect("the learner")
}

/// [`adaptive_run`] in a new directory: how it ended, the counters of its checkpoint and the
/// figures of its record.
fn adaptive_outcome(
    name: &str,
    stop_at_last: bool,
) -> (LearnerExit, crate::Counters, proto::Metrics) {
    let dir = tempfile::tempdir().unwrap();
    let exit = adaptive_run(dir.path(), name, stop_at_last);
    let counters = crate::checkpoint::load(&crate::store::checkpoint_path(dir.path()))
        .expect("a checkpoint")
        .core
        .counters();
    let figures = crate::record::read(dir.path()).expect("the run's figures");
    (exit, counters, figures)
}

/// Issue 52: Ctrl-C while the adaptive schedule trains the updates its last episodes are owed
/// stops the run (`Stopped`, checkpointed: the run is not complete), where it used to break off
/// the top-up and report `Finished`.
#[test]
fn a_stop_during_the_adaptive_top_up_stops_the_run() {
    let (exit, c, figures) = adaptive_outcome("topstop", true);
    assert_eq!(exit, LearnerExit::Stopped);
    assert_eq!(
        c.rl_episodes, EPISODES,
        "the stop came after the last episode"
    );
    let ratio = figures.values["updates_per_episode"];
    assert!(
        ratio < RATIO,
        "the top-up was cut short ({ratio} updates per episode)"
    );
}

/// Issue 52: the learner's final figures are part of the run's record, written durably before
/// the process exits (`launch` puts them in `run.json`): the replay ratio realised from the
/// final counters, counted from where this process started RL, and the figures the live
/// metrics carry. Before, they travelled only as best-effort metrics, and a run whose monitor
/// received none had no `learner_updates_per_episode`.
#[test]
fn the_final_figures_are_in_the_run_directory_when_the_learner_exits() {
    let (exit, c, figures) = adaptive_outcome("figures", false);
    assert_eq!(exit, LearnerExit::Finished);
    let v = &figures.values;
    let (e0, u0) = (v["rl_start_episodes"] as u64, v["rl_start_updates"] as u64);
    assert_eq!(c.rl_episodes - e0, EPISODES);
    assert_eq!(
        v["updates_per_episode"],
        (c.updates - u0) as f64 / EPISODES as f64
    );
    assert_eq!(v["updates_per_episode"], RATIO, "the top-up was done");
    assert_eq!(figures.episodes, EPISODES);
    assert_eq!(v["updates"], c.updates as f64);
    for k in ["policy_lag_p95", "wait_s", "train_s"] {
        assert!(v.contains_key(k), "{k} in {v:?}");
    }
}

/// Issue 52: the linger after the run follows who is alive with the training's capped tracker.
/// Before, it kept every evaluator token it saw (a flood grew its set without bound, and the
/// learner lingered for all of them).
#[test]
fn the_linger_tracks_evaluators_with_the_cap() {
    let dir = tempfile::tempdir().unwrap();
    let port = testkit::free_port();
    let run = RunId::new(format!("linger{}", std::process::id())).unwrap();
    let t = transport(&run, SenderId::learner(), port, true);
    let status = Heartbeat::new(&t).unwrap();
    let spec = adaptive_spec();
    let opts = options(dir.path(), &run, PATIENCE);
    let restored = restore(&spec, &opts, Probe::none()).unwrap();
    let mut l = Learner::new(&t, &status, &spec, &opts, restored.state).unwrap();
    let evaluator = |index: u32| Member {
        sender: SenderId::evaluator(index),
        instance: 1,
    };
    // One evaluator alive when the linger starts; a flood of others joins during it.
    l.on_alive(AliveEvent::Joined(evaluator(0)));
    let stop = AtomicBool::new(false);
    let mut flood = (1..2 * MAX_ACTORS as u32).map(|i| AliveEvent::Joined(evaluator(i)));
    training::linger(
        &mut l,
        |_| {
            let ev = flood.next();
            if ev.is_none() {
                stop.store(true, Ordering::SeqCst);
            }
            Ok(ev)
        },
        &stop,
    )
    .unwrap();
    assert_eq!(l.members.evaluators.len(), MAX_ACTORS);
}
