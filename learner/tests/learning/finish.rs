//! Issue 44, the end of a run and the adaptive mode's rounds: the learner sends its final weights
//! (carrying the final RL episode count) before the `Finished` control, which names their
//! version; an evaluator that sees `Finished` before those weights waits for them and validates
//! them, never the round before; a round of updates whose target refresh is not finite
//! re-synchronises the target network or fails, never repeats for ever.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use evaluator::process::{EvaluatorExit, EvaluatorOptions};
use learner::process::{LearnerExit, LearnerOptions};
use learner::LearnerCore;
use policy::method::{Method, ReplayRatio, TrainConfig};
use policy::rollout::{rollout, Behaviour};
use proto::{keys, Control, RunId, RunPhase, SenderId};
use testkit::free_port;

use crate::run::{episode, spec, transport};

const PATIENCE: Duration = Duration::from_secs(120);

/// The adaptive learner as a process (in a thread) fed by a stand-in actor: the first
/// `Finished` control it sends names the version of weights that carry the final RL episode
/// count. Before the fix it went out with the last episode, naming weights of the round before
/// (trained on one episode fewer), and the final rounds' weights came after it.
#[test]
fn the_finished_control_names_the_final_weights() {
    const EPISODES: u64 = 12;
    let port = free_port();
    let run = RunId::new(format!("fin{}", std::process::id())).unwrap();
    let t = transport(&run, SenderId::learner(), port, true);
    let mut train = TrainConfig::default();
    train.imitation.episodes = 2;
    train.imitation.epochs = 1;
    train.rl.episodes = EPISODES;
    train.rl.batches_per_episode = 2;
    train.rl.replay_ratio = Some(ReplayRatio { min: 3.0, max: 3.0 });
    let spec = spec(train);
    let dir = tempfile::tempdir().unwrap();
    let opts = LearnerOptions {
        run_dir: dir.path().to_path_buf(),
        run_id: run.to_string(),
        in_flight_per_actor: EPISODES,
        metrics_interval: Duration::from_millis(100),
        linger: Duration::from_millis(300),
    };
    let monitor = transport(&run, SenderId::monitor(0), port, false);
    // Latest-value topics: polled often enough to see every value that stands for a while.
    let controls = monitor.latest_subscriber(&keys::control(&run)).unwrap();
    let weights = monitor.latest_subscriber(&keys::weights(&run)).unwrap();
    let stop = AtomicBool::new(false);
    let (exit, seen_controls, seen_weights) = std::thread::scope(|s| {
        let learner = s.spawn(|| learner::process::run(&t, &spec, &opts, &stop));
        let actor = transport(&run, SenderId::actor(0), port, false);
        let _alive = actor.declare_alive().unwrap();
        let out = actor
            .publisher(&keys::transitions(&run, 0))
            .expect("publisher");
        let mut seen_controls: Vec<std::sync::Arc<proto::Message<Control>>> = Vec::new();
        let mut seen_weights = Vec::new();
        let deadline = Instant::now() + PATIENCE;
        let mut sent = 0;
        while !learner.is_finished() {
            assert!(Instant::now() < deadline, "the run did not finish");
            if let Some(w) = weights.next(Duration::ZERO).unwrap() {
                seen_weights.push((w.body.version, w.body.rl_episodes));
            }
            if let Some(c) = controls.next(Duration::from_millis(5)).unwrap() {
                // Every episode at once, once the learner trains.
                if c.body.phase == RunPhase::Training && sent == 0 {
                    for k in 0..EPISODES {
                        out.publish(0, &episode(&spec, k)).unwrap();
                    }
                    sent = EPISODES;
                }
                seen_controls.push(c);
            }
        }
        stop.store(true, Ordering::SeqCst);
        if let Some(w) = weights.next(Duration::from_millis(200)).unwrap() {
            seen_weights.push((w.body.version, w.body.rl_episodes));
        }
        if let Some(c) = controls.next(Duration::from_millis(200)).unwrap() {
            seen_controls.push(c);
        }
        (learner.join().unwrap(), seen_controls, seen_weights)
    });
    assert_eq!(exit.expect("the learner"), LearnerExit::Finished);
    let first = seen_controls
        .iter()
        .find(|c| c.body.phase == RunPhase::Finished)
        .expect("a Finished control");
    let version = first.header.policy_version;
    assert_eq!(
        first.body.final_rl_episodes,
        Some(EPISODES),
        "Finished says how many RL episodes the final weights carry"
    );
    let of_version: Vec<_> = seen_weights
        .iter()
        .filter(|(v, _)| *v == version)
        .map(|(_, rl)| *rl)
        .collect();
    assert!(
        !of_version.is_empty() && of_version.iter().all(|rl| *rl == Some(EPISODES)),
        "the first Finished control names weights version {version}, which carry RL episodes {of_version:?} (weights seen: {seen_weights:?})"
    );
}

/// An evaluator that sees `Finished` before the final weights have reached it waits for them
/// (the control's version) and validates those, labelled with the final RL episode count. Before
/// the fix it validated the weights it had, of the round before, and left.
#[test]
fn the_evaluator_validates_the_final_weights_even_when_they_come_late() {
    the_final_weights_come_late((5, 39));
}

/// The same when the earlier weights have the final version: the last episode was taken after
/// the last round of updates (the adaptive mode owed it none), so the final weights repeat that
/// round's version with one more RL episode. `Finished` says how many; before the fix the
/// evaluator labelled the final validation with the earlier count (seen once in a loaded CI as
/// a distributed 6-episode run whose last validation read 5, tests/cli_train.rs).
#[test]
fn the_evaluator_labels_the_final_weights_by_their_episodes_when_their_version_repeats() {
    the_final_weights_come_late((6, 39));
}

/// The learner's end seen by an evaluator in the worst order: weights `early` (version, RL
/// episodes), then `Finished` naming version 6 and 40 episodes, then, late, the final weights
/// (version 6, 40 episodes). The run's last validation must be of those.
fn the_final_weights_come_late(early: (u64, u64)) {
    let port = free_port();
    let run = RunId::new(format!("fev{}x{}", std::process::id(), early.0)).unwrap();
    let learner = transport(&run, SenderId::learner(), port, true);
    let mut train = TrainConfig::default();
    train.imitation.epochs = 1;
    train.rl.episodes = 40;
    train.validation_every_episodes = 1000;
    train.validation_episodes = 2;
    let spec = spec(train);
    let dir = tempfile::tempdir().unwrap();
    let opts = EvaluatorOptions {
        every_episodes: 0,
        episodes_per_setting: 1,
        seed_start: 1000,
        settings: vec![spec.setting],
        threads: 1,
        out_dir: dir.path().to_path_buf(),
        final_report: false,
    };
    let net = policy::ValueNet::new(spec.method.net().unwrap(), 1).unwrap();
    let message = |version, rl| {
        policy::wire::weights_message(&net, version)
            .unwrap()
            .with_rl_episodes(rl)
    };
    let weights = learner.latest_publisher(&keys::weights(&run)).unwrap();
    let control = learner.latest_publisher(&keys::control(&run)).unwrap();
    // Weights published before the last episode, then `Finished` naming version 6.
    weights
        .publish(early.0, &message(early.0, early.1))
        .unwrap();
    let finished = Control {
        phase: RunPhase::Finished,
        epsilon: 0.0,
        credits: Vec::new(),
        final_rl_episodes: Some(40),
    };
    control.publish(6, &finished).unwrap();
    let ev = transport(&run, SenderId::evaluator(0), port, false);
    let stop = AtomicBool::new(false);
    let validations = dir.path().join("validation.jsonl");
    let exit = std::thread::scope(|s| {
        let evaluator = s.spawn(|| evaluator::process::run(&ev, &spec, &opts, &stop, None));
        // The final weights come late: once the evaluator has gone (before the fix: it took
        // the weights it had) or after a while in which it has seen both messages.
        let deadline = Instant::now() + Duration::from_secs(5);
        while !evaluator.is_finished() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(50));
        }
        weights.publish(6, &message(6, 40)).unwrap();
        let deadline = Instant::now() + PATIENCE;
        while !evaluator.is_finished() {
            assert!(Instant::now() < deadline, "the evaluator did not finish");
            let _ = weights.republish();
            std::thread::sleep(Duration::from_millis(50));
        }
        evaluator.join().unwrap()
    });
    assert_eq!(exit.expect("the evaluator"), EvaluatorExit::Finished(None));
    let text = std::fs::read_to_string(&validations).unwrap();
    let last: serde_json::Value = serde_json::from_str(text.lines().last().unwrap()).unwrap();
    assert_eq!(
        (last["episode"].as_u64(), last["policy_version"].as_u64()),
        (Some(40), Some(6)),
        "the run's last validation is of its final weights:\n{text}"
    );
}

/// An adaptive run's core after imitation whose networks are those of `online` and `target`
/// (`true`: its weights times 1e30, whose values overflow f32; the weights themselves stay
/// finite). Made through a checkpoint, its weight bytes replaced and its checksum recomputed:
/// the state a learner would resume, nothing the core's own API lets a test set.
fn core_with_overflowing(online: bool, target: bool) -> LearnerCore {
    let cfg = sim::SimConfig::default();
    let mut train = TrainConfig::default();
    train.rl.batches_per_episode = 2;
    train.rl.replay_ratio = Some(ReplayRatio { min: 2.0, max: 4.0 });
    let mut core = LearnerCore::new(Method::Sarl, train, cfg.humans.count, cfg.dt_s, 1).unwrap();
    let mut env = sim::Env::new(cfg.clone(), "env1-invisible".parse().unwrap(), 0).unwrap();
    for seed in 0..3 {
        let orca = Behaviour::Orca {
            safety_space_m: 0.0,
        };
        core.add_episode(&rollout(&mut env, seed, orca).unwrap(), true)
            .unwrap();
    }
    core.start_rl().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("latest.ckpt");
    let run = learner::checkpoint::RunInfo {
        run_id: "overflow".into(),
        setting: "env1-invisible".into(),
        run_seed: 1,
        accepted_below: Default::default(),
    };
    learner::checkpoint::save(&path, &core, &cfg, &run).unwrap();
    // Online and target are the same weights after `start_rl`: the first copy in the payload
    // is the online network's, the second the target's (the checkpoint's field order).
    let le = |p: &[f32]| p.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let params = core.online().params();
    let (plain, huge) = (
        le(params),
        le(&params.iter().map(|p| p * 1e30).collect::<Vec<_>>()),
    );
    let mut bytes = std::fs::read(&path).unwrap();
    const HEAD: usize = 8 + 4 + 8;
    let end = bytes.len() - 4;
    let at: Vec<usize> = (HEAD..end - plain.len())
        .filter(|&i| bytes[i..i + plain.len()] == plain[..])
        .take(2)
        .collect();
    assert_eq!(at.len(), 2, "both networks' weights in the checkpoint");
    for (k, overflow) in [online, target].into_iter().enumerate() {
        if overflow {
            bytes[at[k]..at[k] + huge.len()].copy_from_slice(&huge);
        }
    }
    let crc = crc32fast::hash(&bytes[HEAD..end]);
    bytes[end..].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    learner::checkpoint::load(&path).unwrap().core
}

/// The adaptive mode's rounds when the target network's values overflow: the round skips its
/// refresh, re-synchronises the target network from the online one, and the next round trains
/// (before the fix every round skipped again: no update, no error, and the learner's actors
/// starved for ever). When the online network overflows too, nothing can change it: an error
/// at once, not rounds for ever.
#[test]
fn a_round_whose_targets_are_not_finite_resynchronises_or_fails() {
    let mut core = core_with_overflowing(false, true);
    let updates = core.counters().updates;
    core.train_round(2)
        .expect("a skipped refresh is not an error");
    assert_eq!(core.skipped_refreshes(), 1);
    assert_eq!(core.counters().updates, updates);
    for _ in 0..3 {
        core.train_round(2).unwrap();
    }
    assert_eq!(
        core.counters().updates,
        updates + 6,
        "training goes on after the target network is re-synchronised ({} refreshes skipped)",
        core.skipped_refreshes()
    );

    let mut core = core_with_overflowing(true, true);
    let mut outcome = Ok(f32::NAN);
    for _ in 0..10 {
        outcome = core.train_round(2);
        if outcome.is_err() {
            break;
        }
    }
    let e = outcome.expect_err("rounds without updates and without an error");
    assert!(
        e.to_string().contains("online network"),
        "a clear error: {e}"
    );
    assert_eq!(core.skipped_refreshes(), 1);
}
