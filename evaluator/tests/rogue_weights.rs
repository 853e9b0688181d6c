//! The evaluator process against rogue weights over zenoh (peer mode, no router to keep
//! anyone out): a weights message at version 10⁶ from an actor is rejected by sender (only the
//! learner publishes weights and control), and one at a version near `u64::MAX` under a forged
//! learner header is evaluated once but silences nothing: the real learner's next due
//! snapshot is evaluated, and the run's end is noticed (the process returns, no hang).

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use evaluator::process::{EvaluatorExit, EvaluatorOptions};
use policy::method::{Method, RunSpec, TrainConfig};
use policy::wire::weights_message;
use policy::{NetConfig, ValueNet};
use proto::{Control, RunId, RunPhase, SenderId};
use sim::config::{EnvKind, Setting};
use testkit::free_port;
use transport::{Transport, TransportConfig, ZenohConfig};

const PATIENCE: Duration = Duration::from_secs(120);

fn open(run: &RunId, sender: SenderId, listen: &str, connect: &[String]) -> Transport {
    let mut c = TransportConfig::new(run.clone(), sender);
    c.zenoh = ZenohConfig::peer(vec![listen.to_string()], connect.to_vec());
    Transport::open(c).expect("open transport")
}

fn report_path(dir: &Path, version: u64) -> std::path::PathBuf {
    dir.join(format!("eval-{version:06}.json"))
}

fn wait_for(what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = Instant::now() + PATIENCE;
    while !cond() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Sets the flag when dropped, also while unwinding from a failed assertion.
struct StopOnDrop<'a>(&'a AtomicBool);

impl Drop for StopOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, std::sync::atomic::Ordering::SeqCst);
    }
}

#[test]
fn a_rogue_high_version_neither_hangs_nor_silences_the_evaluator() {
    let run = RunId::new(format!("ev{}", std::process::id())).unwrap();
    let hub = format!("tcp/127.0.0.1:{}", free_port());
    let learner = open(&run, SenderId::learner(), &hub, &[]);
    let peer = "tcp/127.0.0.1:0";
    let connect = [hub.clone()];
    let evaluator_t = open(&run, SenderId::evaluator(0), peer, &connect);
    let rogue_actor = open(&run, SenderId::actor(0), peer, &connect);
    let forged_learner = open(&run, SenderId::learner(), peer, &connect);

    let mut train = TrainConfig::default();
    train.imitation.epochs = 2;
    train.validation_every_episodes = 0;
    let spec = RunSpec {
        method: Method::Sarl,
        setting: Setting::new(EnvKind::Env1, false),
        sim: sim::SimConfig::default(),
        train,
        seed: 0,
    };
    let il = spec.train.imitation.epochs as u64;
    let out = tempfile::tempdir().unwrap();
    let opts = EvaluatorOptions {
        every_episodes: 10,
        episodes_per_setting: 1,
        seed_start: 1000,
        settings: vec![spec.setting],
        threads: 1,
        out_dir: out.path().to_path_buf(),
        final_report: false,
    };
    let net = ValueNet::new(NetConfig::sarl(), 0).unwrap();
    let weights = |v: u64| weights_message(&net, v).unwrap();
    let keys_w = proto::keys::weights(&run);
    let keys_c = proto::keys::control(&run);
    let wp = learner.latest_publisher(&keys_w).unwrap();
    let cp = learner.latest_publisher(&keys_c).unwrap();
    let control = |phase| Control {
        phase,
        epsilon: 0.5,
        credits: Vec::new(),
        final_rl_episodes: None,
    };
    cp.publish(il, &control(RunPhase::Training)).unwrap();

    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let evaluator =
            s.spawn(|| evaluator::process::run(&evaluator_t, &spec, &opts, &stop, None));
        // A failed check stops the evaluator (the scope waits for it before reporting).
        let _stop_on_failure = StopOnDrop(&stop);
        // 1. The learner's weights after 10 RL episodes: evaluated.
        wp.publish(il + 10, &weights(il + 10)).unwrap();
        wait_for("the first snapshot's report", || {
            report_path(out.path(), il + 10).exists()
        });

        // 2. An actor's weights at version 10⁶: refused by sender, never evaluated.
        let rogue = rogue_actor.latest_publisher(&keys_w).unwrap();
        for _ in 0..5 {
            rogue.publish(1_000_000, &weights(1_000_000)).unwrap();
            std::thread::sleep(Duration::from_millis(100));
        }
        wp.publish(il + 20, &weights(il + 20)).unwrap();
        wait_for(
            "the learner's next snapshot after the actor's rogue",
            || report_path(out.path(), il + 20).exists(),
        );
        assert!(
            !report_path(out.path(), 1_000_000).exists(),
            "weights from an actor were evaluated"
        );
        assert!(
            evaluator_t.rejected_count() > 0,
            "the actor's weights were not counted as rejected"
        );

        // 3. A forged learner header at a version near u64::MAX: no loop by the version
        //    (evaluated like any due snapshot), and the real learner is followed afterwards.
        let huge = u64::MAX - 1;
        let forged = forged_learner.latest_publisher(&keys_w).unwrap();
        forged.publish(huge, &weights(huge)).unwrap();
        wait_for("the forged snapshot to be looked at", || {
            report_path(out.path(), huge).exists()
        });
        wp.publish(il + 30, &weights(il + 30)).unwrap();
        wait_for(
            "the learner's snapshot after the huge version (silenced?)",
            || report_path(out.path(), il + 30).exists(),
        );

        // 4. The run ends: the evaluator returns.
        cp.publish(il + 30, &control(RunPhase::Finished)).unwrap();
        let t0 = Instant::now();
        while !evaluator.is_finished() {
            assert!(t0.elapsed() < PATIENCE, "the evaluator hangs");
            std::thread::sleep(Duration::from_millis(50));
        }
        let exit = evaluator
            .join()
            .unwrap()
            .expect("the evaluator ends cleanly");
        assert!(matches!(exit, EvaluatorExit::Finished(None)));
    });
}
