//! The evaluator in the walled settings (issue 53): its wire report carries wall collisions,
//! people collisions and frozen robots apart only where there are walls (a report of the
//! paper's settings is encoded as before), and the evaluator process scores a walled run's
//! weights end to end over zenoh.

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use evaluator::process::{markdown, report, EvaluatorExit, EvaluatorOptions};
use evaluator::{evaluate, Subject};
use policy::lookahead::HumanModel;
use policy::method::{Method, RunSpec, TrainConfig};
use policy::wire::weights_message;
use policy::{NetConfig, ValueNet};
use proto::{Control, Header, RunId, RunPhase, SenderId};
use sim::{Setting, SimConfig};
use testkit::free_port;
use transport::{Transport, TransportConfig, ZenohConfig};

const PATIENCE: Duration = Duration::from_secs(120);

fn setting(name: &str) -> Setting {
    name.parse().unwrap()
}

fn orca() -> Subject<'static> {
    Subject {
        method: Method::Orca,
        net: None,
        gamma: 0.9,
        human_model: HumanModel::Orca,
        terminal_previews: false,
        planning_top_k: 0,
        planning_breadth: 0,
        shield_s: 0.0,
        progress_tolerance: 0.0,
        orca_safety_space_m: 0.0,
    }
}

#[test]
fn the_wire_report_splits_collisions_in_walled_settings_only() {
    let settings = [
        setting("env1-visible"),
        setting("corridor"),
        setting("doorway"),
    ];
    let results = evaluate(orca(), &SimConfig::default(), &settings, 1000, 10, 2).unwrap();
    let r = report(&results, 7, true);
    let paper = &r.settings[0];
    assert_eq!(
        (
            paper.wall_collision_rate,
            paper.people_collision_rate,
            paper.frozen_rate
        ),
        (None, None, None)
    );
    for (x, res) in r.settings[1..].iter().zip(&results[1..]) {
        let a = &res.aggregate;
        assert_eq!(x.wall_collision_rate, Some(a.wall_collision_rate()));
        assert_eq!(x.people_collision_rate, Some(a.people_collision_rate()));
        assert_eq!(x.frozen_rate, Some(a.frozen_rate()));
        let split = x.wall_collision_rate.unwrap() + x.people_collision_rate.unwrap();
        assert!((split - x.collision_rate).abs() < 1e-12, "{x:?}");
    }
    // Over the wire and back.
    let header = Header::new::<proto::EvalReport>(
        RunId::new("walls").unwrap(),
        SenderId::evaluator(0),
        0,
        3,
    );
    let bytes = proto::encode(&header, &r).unwrap();
    let back: proto::Message<proto::EvalReport> = proto::decode(&bytes).unwrap();
    assert_eq!(back.body, r);
    // The Markdown: walled columns, "–" in the paper setting's row, averages of paper settings
    // only (one per visibility here: none).
    let md = markdown(&r, "orca", 3);
    assert!(
        md.contains("| Wall coll. | People coll. | Frozen |"),
        "{md}"
    );
    assert!(md.contains("| – | – | – |"), "{md}");
    assert!(md.contains("| corridor | 10 |"), "{md}");
    assert!(!md.contains("average"), "{md}");

    // The paper's settings alone: no trace of walls in the bytes or the table.
    let paper_only = report(&results[..1], 7, true);
    let bytes = proto::encode(&header, &paper_only).unwrap();
    let needle = b"collision_rate";
    let mentions = bytes.windows(needle.len()).filter(|w| w == needle).count();
    assert_eq!(mentions, 1, "only `collision_rate` itself");
    assert!(!markdown(&paper_only, "orca", 3).contains("Wall"));
}

/// A rogue value is refused at decoding like any other rate.
#[test]
fn a_wall_collision_rate_outside_zero_one_is_refused() {
    let mut r = proto::fixtures::eval_report();
    r.settings[0].wall_collision_rate = Some(1.5);
    let header = Header::new::<proto::EvalReport>(
        RunId::new("walls").unwrap(),
        SenderId::evaluator(0),
        0,
        3,
    );
    let err = proto::encode(&header, &r).unwrap_err().to_string();
    assert!(err.contains("wall_collision_rate"), "{err}");
}

fn open(run: &RunId, sender: SenderId, listen: &str, connect: &[String]) -> Transport {
    let mut c = TransportConfig::new(run.clone(), sender);
    c.zenoh = ZenohConfig::peer(vec![listen.to_string()], connect.to_vec());
    Transport::open(c).expect("open transport")
}

/// A run in the corridor through the evaluator process: the learner's final weights are
/// scored on the corridor, and the report (returned, and on disk) has the three rates.
#[test]
fn the_evaluator_process_reports_a_walled_run() {
    let run = RunId::new(format!("wall{}", std::process::id())).unwrap();
    let hub = format!("tcp/127.0.0.1:{}", free_port());
    let learner = open(&run, SenderId::learner(), &hub, &[]);
    let evaluator_t = open(
        &run,
        SenderId::evaluator(0),
        "tcp/127.0.0.1:0",
        std::slice::from_ref(&hub),
    );
    let mut train = TrainConfig::default();
    train.imitation.epochs = 2;
    train.validation_every_episodes = 0;
    let spec = RunSpec {
        method: Method::Sarl,
        setting: setting("corridor"),
        sim: SimConfig::default(),
        train,
        seed: 0,
    };
    let il = spec.train.imitation.epochs as u64;
    let out = tempfile::tempdir().unwrap();
    let opts = EvaluatorOptions {
        every_episodes: 0,
        episodes_per_setting: 3,
        seed_start: 1000,
        settings: vec![spec.setting],
        threads: 1,
        out_dir: out.path().to_path_buf(),
        final_report: true,
    };
    let net = ValueNet::new(NetConfig::sarl(), 0).unwrap();
    let version = il + 10;
    let weights = learner
        .latest_publisher(&proto::keys::weights(&run))
        .unwrap();
    let control = learner
        .latest_publisher(&proto::keys::control(&run))
        .unwrap();
    let finished = Control {
        phase: RunPhase::Finished,
        epsilon: 0.0,
        credits: Vec::new(),
        final_rl_episodes: None,
    };
    let stop = AtomicBool::new(false);
    let exit = std::thread::scope(|s| {
        let evaluator =
            s.spawn(|| evaluator::process::run(&evaluator_t, &spec, &opts, &stop, None));
        // As the learner does at the end of a run: the final weights and `Finished`, repeated
        // until the evaluator leaves.
        let t0 = Instant::now();
        while !evaluator.is_finished() {
            if t0.elapsed() > PATIENCE {
                stop.store(true, std::sync::atomic::Ordering::SeqCst);
            }
            weights
                .publish(version, &weights_message(&net, version).unwrap())
                .unwrap();
            control.publish(version, &finished).unwrap();
            std::thread::sleep(Duration::from_millis(100));
        }
        evaluator.join().unwrap()
    });
    let Ok(EvaluatorExit::Finished(Some(r))) = exit else {
        panic!("the evaluator did not finish with a report: {exit:?}");
    };
    let x = &r.settings[0];
    assert_eq!((x.setting.as_str(), x.episodes), ("corridor", 3));
    assert!(x.wall_collision_rate.is_some() && x.people_collision_rate.is_some());
    assert!(x.frozen_rate.is_some());
    let json = std::fs::read_to_string(out.path().join("report.json")).unwrap();
    for key in [
        "wall_collision_rate",
        "people_collision_rate",
        "frozen_rate",
    ] {
        assert!(json.contains(key), "{key}: {json}");
    }
    let md = std::fs::read_to_string(out.path().join("report.md")).unwrap();
    assert!(
        md.contains("| Wall coll. | People coll. | Frozen |"),
        "{md}"
    );
}
