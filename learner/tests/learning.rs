//! Tests that prove learning: imitation reduces the loss; after imitation alone SARL succeeds on
//! env1-invisible far more often than a random policy; a short RL run keeps the loss finite and
//! moves the weights; a short run is reproducible bit for bit; checkpoints round-trip. `crash`:
//! the learner's persistence through kills, torn writes, power losses and a full disk;
//! `imitation_retry`: the learner process retries the checkpoint after imitation on a full disk;
//! `finish`: the final weights before `Finished`, validated by the evaluator, and the adaptive
//! mode's rounds never repeat a non-finite target refresh for ever.

#[path = "learning/crash.rs"]
mod crash;
#[path = "learning/finish.rs"]
mod finish;
#[path = "learning/imitation_retry.rs"]
mod imitation_retry;
#[path = "support/run.rs"]
mod run;

use evaluator::{evaluate, Subject};
use learner::checkpoint::{self, CheckpointError, RunInfo};
use learner::LearnerCore;
use policy::lookahead::{HumanModel, Lookahead};
use policy::method::{Method, TrainConfig};
use policy::rollout::{episode_seed, rollout, Behaviour};
use rand::{Rng, SeedableRng};
use sim::{run_episode, Aggregate, Env, Setting, SimConfig};

const DEMOS: u64 = 300;
const EPOCHS: u32 = 20;

fn setting() -> Setting {
    "env1-invisible".parse().unwrap()
}

fn imitated(method: Method, demos: u64, epochs: u32) -> (LearnerCore, Vec<f32>) {
    let mut train = TrainConfig::default();
    train.imitation.episodes = demos;
    let sim_cfg = method.sim_config(&SimConfig::default());
    let mut env = Env::new(sim_cfg, setting(), 0).unwrap();
    let mut core = LearnerCore::new(method, train.clone(), 10, 0.25, 7).unwrap();
    for k in 0..demos {
        let ep = rollout(
            &mut env,
            episode_seed(7, 0, k),
            Behaviour::Orca {
                safety_space_m: train.imitation.safety_space_m,
            },
        )
        .unwrap();
        core.add_episode(&ep, true).unwrap();
    }
    let mut losses = vec![core.imitation_loss().unwrap()];
    core.imitation(epochs, |_, l| losses.push(l)).unwrap();
    losses.push(core.imitation_loss().unwrap());
    (core, losses)
}

fn random_policy_success(episodes: u32) -> Aggregate {
    let mut agg = Aggregate::default();
    let mut env = Env::new(SimConfig::default(), setting(), 1000).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for k in 0..episodes as u64 {
        env.reset(1000 + k).unwrap();
        let n = env.action_set().len();
        let ep = run_episode(&mut env, |_| rng.gen_range(0..n), false).unwrap();
        agg.add(&ep.summary);
    }
    agg
}

#[test]
fn imitation_learns_a_policy_far_better_than_random() {
    let (core, losses) = imitated(Method::Sarl, DEMOS, EPOCHS);
    let (first, last) = (losses[0], *losses.last().unwrap());
    println!(
        "imitation MSE on {} transitions: untrained {first:.5}, after {EPOCHS} epochs {last:.5} ({:.1}x lower)",
        core.replay().len(),
        first / last
    );
    assert!(last.is_finite());
    assert!(
        last < first / 4.0,
        "imitation loss {first} -> {last}: not reduced 4x"
    );

    let subject = Subject {
        method: Method::Sarl,
        net: Some(core.online()),
        gamma: 0.9,
        human_model: HumanModel::Orca,
        terminal_previews: false,
        planning_top_k: 0,
        planning_breadth: 0,
        shield_s: 0.0,
        progress_tolerance: 0.0,
        orca_safety_space_m: 0.0,
    };
    let res = evaluate(subject, &SimConfig::default(), &[setting()], 1000, 100, 2).unwrap();
    let sarl = res[0].aggregate;
    let random = random_policy_success(100);
    println!(
        "env1-invisible, 100 test seeds: SARL after imitation success {:.2} (coll {:.2}, timeout {:.2}); random policy success {:.2}",
        sarl.success_rate(),
        sarl.collision_rate(),
        sarl.timeout_rate(),
        random.success_rate()
    );
    assert!(
        random.success_rate() <= 0.05,
        "random policy succeeded {}",
        random.success_rate()
    );
    assert!(
        sarl.success_rate() >= 0.15,
        "SARL after imitation only {}",
        sarl.success_rate()
    );
}

/// A tiny run: a few demos, a couple of epochs, then `rl_episodes` RL episodes.
fn short_run(rl_episodes: u64) -> LearnerCore {
    let (mut core, _) = imitated(Method::Fsrl, 20, 2);
    core.start_rl().unwrap();
    let mut env = Env::new(Method::Fsrl.sim_config(&SimConfig::default()), setting(), 0).unwrap();
    let mut lookahead = Lookahead::new(0.9, HumanModel::Orca, Method::Fsrl.human_order());
    for k in 0..rl_episodes {
        let eps = core.epsilon();
        let version = core.counters().policy_version;
        let ep = rollout(
            &mut env,
            episode_seed(7, 1, k),
            Behaviour::Net {
                net: core.online(),
                lookahead: &mut lookahead,
                epsilon: eps,
                policy_version: version,
            },
        )
        .unwrap();
        core.add_episode(&ep, false).unwrap();
        let loss = core.train_rl(20).unwrap();
        assert!(loss.is_finite(), "RL loss {loss} at episode {k}");
    }
    core
}

#[test]
fn a_short_rl_run_keeps_the_loss_finite_and_moves_the_weights() {
    let (il, _) = imitated(Method::Fsrl, 20, 2);
    let before = il.online().params().to_vec();
    let core = short_run(6);
    let after = core.online().params();
    let moved = before.iter().zip(after).filter(|(a, b)| a != b).count();
    let change: f64 = before
        .iter()
        .zip(after)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    println!(
        "RL moved {moved} of {} weights, L2 change {change:.4}",
        before.len()
    );
    // Units that imitation left dead (ReLU) get no gradient, so not every weight moves.
    assert!(moved > before.len() / 10, "only {moved} weights moved");
    assert!(change > 1e-4);
    let c = core.counters();
    assert_eq!(c.rl_episodes, 6);
    assert_eq!(c.demo_episodes, 20);
    assert!(c.imitation_done);
    // ε decays linearly from 0.5 over the schedule's decay episodes.
    let decay = core.config().rl.epsilon_decay_episodes as f64;
    assert!((core.epsilon() - (0.5 - 0.4 * 6.0 / decay)).abs() < 1e-12);
}

#[test]
fn a_short_run_is_reproducible_bit_for_bit() {
    let a = short_run(3);
    let b = short_run(3);
    assert_eq!(a.online().params(), b.online().params());
    assert_eq!(a.trainer().target().params(), b.trainer().target().params());
    assert!(a.replay() == b.replay(), "replays differ");
    assert_eq!(a.counters(), b.counters());
}

#[test]
fn checkpoints_load_back_bit_exact_and_refuse_damage() {
    let core = short_run(2);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run.ckpt");
    let run = RunInfo {
        run_id: "test".into(),
        setting: setting().name().into(),
        run_seed: 7,
        accepted_below: Default::default(),
    };
    let sim_cfg = Method::Fsrl.sim_config(&SimConfig::default());
    checkpoint::save(&path, &core, &sim_cfg, &run).unwrap();
    let loaded = checkpoint::load(&path).unwrap();
    assert_eq!(loaded.run, run);
    assert_eq!(loaded.sim, sim_cfg);
    let l = &loaded.core;
    assert_eq!(l.method(), Method::Fsrl);
    assert_eq!(l.config(), core.config());
    assert_eq!(l.online().params(), core.online().params());
    assert_eq!(
        l.trainer().target().params(),
        core.trainer().target().params()
    );
    assert_eq!(l.trainer().adam(), core.trainer().adam());
    assert!(l.replay() == core.replay(), "replay differs after loading");
    assert_eq!(l.counters(), core.counters());

    // Continuing from the checkpoint gives exactly what continuing the original gives.
    let mut original = core;
    let mut resumed = loaded.core;
    let lo = original.train_rl(5).unwrap();
    let lr = resumed.train_rl(5).unwrap();
    assert_eq!(lo.to_bits(), lr.to_bits());
    assert_eq!(original.online().params(), resumed.online().params());

    let bytes = std::fs::read(&path).unwrap();
    let damaged = dir.path().join("damaged.ckpt");
    // Truncated.
    std::fs::write(&damaged, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(
        checkpoint::load(&damaged),
        Err(CheckpointError::Truncated { .. })
    ));
    // A flipped bit in the payload.
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x10;
    std::fs::write(&damaged, &flipped).unwrap();
    let err = checkpoint::load(&damaged)
        .err()
        .expect("corrupt file must not load");
    assert!(matches!(err, CheckpointError::Corrupt(_)), "{err}");
    // Another format version.
    let mut other = bytes.clone();
    other[8] = 99;
    std::fs::write(&damaged, &other).unwrap();
    let err = checkpoint::load(&damaged).err().unwrap();
    assert!(err.to_string().contains("format version 99"), "{err}");
    // Not a checkpoint at all; a missing file.
    std::fs::write(&damaged, b"hello").unwrap();
    assert!(matches!(
        checkpoint::load(&damaged),
        Err(CheckpointError::NotACheckpoint(_))
    ));
    let err = checkpoint::load(&dir.path().join("missing.ckpt"))
        .err()
        .unwrap();
    assert!(err.to_string().contains("missing.ckpt"), "{err}");
    // Random garbage after a valid header never panics.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    for _ in 0..50 {
        let mut g = bytes[..20].to_vec();
        let n = rng.gen_range(0..200);
        g.extend((0..n).map(|_| rng.gen::<u8>()));
        std::fs::write(&damaged, &g).unwrap();
        assert!(checkpoint::load(&damaged).is_err());
    }
}

#[test]
fn malformed_episodes_are_refused_whole() {
    let mut core = LearnerCore::new(Method::Sarl, TrainConfig::default(), 10, 0.25, 1).unwrap();
    let mut env = Env::new(SimConfig::default(), setting(), 0).unwrap();
    let ep = rollout(
        &mut env,
        5,
        Behaviour::Orca {
            safety_space_m: 0.0,
        },
    )
    .unwrap();
    let mut nan = ep.clone();
    nan.states[1].humans[3].position.x = f64::NAN;
    let err = core.add_episode(&nan, false).unwrap_err();
    assert!(err.to_string().contains("non-finite"), "{err}");
    let mut short = ep.clone();
    short.actions.pop();
    assert!(core.add_episode(&short, false).is_err());
    let mut fewer = ep.clone();
    fewer.states[0].humans.pop();
    assert!(core
        .add_episode(&fewer, false)
        .unwrap_err()
        .to_string()
        .contains("9 humans"));
    assert_eq!(
        core.replay().len(),
        0,
        "nothing of a refused episode is stored"
    );
    assert_eq!(core.counters().rl_episodes, 0);
    assert!(core.add_episode(&ep, false).unwrap());
    assert_eq!(core.replay().len(), ep.steps());
    assert!(LearnerCore::new(Method::Orca, TrainConfig::default(), 10, 0.25, 1).is_err());
}

#[test]
fn cached_value_targets_equal_fresh_ones_from_the_target_network() {
    // 60 RL episodes: the target network is refreshed at episode 50, with new data after it.
    let (mut core, _) = imitated(Method::Sarl, 5, 1);
    core.start_rl().unwrap();
    let mut env = Env::new(SimConfig::default(), setting(), 0).unwrap();
    for k in 0..60 {
        let ep = rollout(
            &mut env,
            episode_seed(3, 1, k),
            Behaviour::Orca {
                safety_space_m: 0.0,
            },
        )
        .unwrap();
        core.add_episode(&ep, false).unwrap();
        core.train_rl(2).unwrap();
    }
    let len = core.replay().len();
    let mut batch = learner::replay::Batch::default();
    core.replay().gather(0..len, &mut batch);
    let next = policy::StateBatch::new(&batch.next_states, len, 10).unwrap();
    let v = core.trainer().target().values(next);
    let mut worst = 0f32;
    for (i, v) in v.iter().enumerate() {
        let fresh = batch.rewards[i] + batch.discounts[i] * v;
        worst = worst.max((fresh - batch.targets[i]).abs());
    }
    assert!(worst < 1e-6, "cached targets differ by up to {worst}");
    // And the online network has moved away from the target since the refresh.
    assert_ne!(core.online().params(), core.trainer().target().params());
}

/// The warm start reports every batch and stops within one: an epoch of the paper's schedule
/// takes tens of seconds, and the learner process drains its transitions (a flood during
/// imitation cannot fill its queue) and sees Ctrl-C on each report. Reporting changes nothing:
/// the losses and weights are `imitation`'s.
#[test]
fn imitation_reports_every_batch_and_stops_within_one() {
    use learner::core::ImitationStep;
    let (mut a, _) = imitated(Method::Sarl, 20, 0);
    let (mut b, _) = imitated(Method::Sarl, 20, 0);
    let batches = a
        .replay()
        .len()
        .div_ceil(TrainConfig::default().imitation.batch_size);
    assert!(batches >= 3, "{batches} batches");
    let mut steps = Vec::new();
    let last = a
        .imitation_steps(2, |s| {
            steps.push(s);
            true
        })
        .unwrap();
    let plain = b.imitation(2, |_, _| {}).unwrap();
    assert_eq!(
        last,
        Some(plain),
        "the same draws and updates as imitation()"
    );
    assert_eq!(a.imitation_loss().unwrap(), b.imitation_loss().unwrap());
    assert_eq!(steps.len(), 2 * batches + 2, "{steps:?}");
    for (epoch, chunk) in steps.chunks(batches + 1).enumerate() {
        for (k, s) in chunk[..batches].iter().enumerate() {
            assert_eq!(
                *s,
                ImitationStep::Batch {
                    epoch: epoch as u32,
                    done: k + 1,
                    batches
                }
            );
        }
        assert!(
            matches!(chunk[batches], ImitationStep::Epoch { epoch: e, .. } if e == epoch as u32)
        );
    }

    // A stop after the third batch of the first epoch: nothing more is fitted, no epoch counted.
    let (mut c, _) = imitated(Method::Sarl, 20, 0);
    let version = c.counters().policy_version;
    let mut seen = 0;
    let stopped = c
        .imitation_steps(2, |_| {
            seen += 1;
            seen < 3
        })
        .unwrap();
    assert_eq!((stopped, seen), (None, 3));
    assert_eq!(c.counters().policy_version, version);

    // Through the warm start the processes run: a stop raised during the first epoch's batches
    // ends it there, and the core stays in imitation (the next start redoes the warm start).
    let mut train = TrainConfig::default();
    train.imitation.episodes = 20;
    train.imitation.epochs = 50;
    let spec = policy::method::RunSpec {
        method: Method::Sarl,
        setting: setting(),
        sim: SimConfig::default(),
        train: train.clone(),
        seed: 7,
    };
    let mut d = LearnerCore::new(Method::Sarl, train, 10, 0.25, 7).unwrap();
    let stop = std::sync::atomic::AtomicBool::new(false);
    let mut reports = Vec::new();
    let finished = learner::imitation::run(&mut d, &spec, &stop, |p| {
        if let learner::imitation::ImitationProgress::Batch { epoch, done, .. } = p {
            reports.push((epoch, done));
            if done == 2 {
                stop.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        }
    })
    .unwrap();
    assert!(!finished);
    assert_eq!(reports, vec![(0, 1), (0, 2)]);
    assert!(!d.counters().imitation_done);
}
