//! Model files (`.fsrlm`): every model shipped in `models/` is the network its method uses and
//! still does exactly what its recorded check says on the recorded test seeds (same outcomes and
//! steps, returns within 1e-6). Without shipped models the same code runs on a model built from
//! a freshly initialised learner, through the library and through `fsrl export-model`, `fsrl
//! eval`, `fsrl plot episode` and `fsrl evaluator --model`; damaged files are clear errors.

mod cli_support;
use cli_support::{fails, ok, s};

use std::path::{Path, PathBuf};

use learner::checkpoint::{self, RunInfo};
use learner::model::{load_policy, ArtifactKind, Model, ModelError};
use learner::LearnerCore;
use policy::method::{Method, TrainConfig};
use sim::{Outcome, SimConfig};

const RETURN_TOLERANCE: f64 = 1e-6;

fn threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The model is what its method trains, and replays its check.
fn assert_reproduces(model: &Model, name: &str) {
    let net = model.net.config();
    assert_eq!(
        Some(net.clone()),
        model.method.net(),
        "{name}: not the network of method {}",
        model.method
    );
    assert_eq!(model.net.params().len(), net.num_params(), "{name}");
    assert!(!model.check.is_empty(), "{name}: no recorded check");
    let again = model.run_check(threads()).unwrap();
    assert_eq!(again.len(), model.check.len(), "{name}");
    for (r, p) in model.check.iter().zip(&again) {
        assert_eq!(r.seed, p.seed, "{name}");
        assert_eq!(
            (r.outcome, r.steps),
            (p.outcome, p.steps),
            "{name}: seed {} ended differently",
            r.seed
        );
        assert!(
            (r.return_sum - p.return_sum).abs() <= RETURN_TOLERANCE,
            "{name}: seed {} return {} recorded, {} now",
            r.seed,
            r.return_sum,
            p.return_sum
        );
    }
    model.verify_check(threads(), RETURN_TOLERANCE).unwrap();
}

#[test]
fn shipped_models_reproduce_their_recorded_check() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|entries| {
            entries
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "fsrlm"))
                .collect()
        })
        .unwrap_or_default();
    files.sort();
    if files.is_empty() {
        eprintln!("note: no models/*.fsrlm yet; the format is exercised by the fresh-model tests");
    }
    for path in &files {
        let name = path.display().to_string();
        let model = Model::load(path).unwrap_or_else(|e| panic!("{e}"));
        assert_reproduces(&model, &name);
        let wins = model
            .check
            .iter()
            .filter(|e| e.outcome == Outcome::ReachGoal)
            .count();
        eprintln!(
            "{name}: {} trained on {}, seed {}: {wins}/{} check episodes reach the goal, reproduced",
            model.method,
            model.setting,
            model.run_seed,
            model.check.len()
        );
    }
}

const SEED: u64 = 11;

/// A learner as `fsrl train` starts it (small replay: nothing is trained).
fn fresh_core(method: Method) -> (LearnerCore, SimConfig, RunInfo) {
    let mut train = TrainConfig::default();
    train.rl.replay_capacity = 64;
    let sim = SimConfig::default();
    let core = LearnerCore::new(method, train, sim.humans.count, sim.dt_s, SEED).unwrap();
    let run = RunInfo {
        run_id: "fresh".into(),
        setting: "env1-invisible".into(),
        run_seed: SEED,
        accepted_below: Default::default(),
    };
    (core, method.sim_config(&sim), run)
}

fn same_model(a: &Model, b: &Model) {
    assert_eq!(a.method, b.method);
    assert_eq!(a.net.config(), b.net.config());
    let bits = |m: &Model| -> Vec<u32> { m.net.params().iter().map(|x| x.to_bits()).collect() };
    assert_eq!(bits(a), bits(b));
    assert_eq!(
        (a.setting, a.run_seed, &a.run_id, a.counters),
        (b.setting, b.run_seed, &b.run_id, b.counters)
    );
    assert_eq!((&a.train, &a.sim), (&b.train, &b.sim));
    assert_eq!(a.check, b.check);
}

#[test]
fn a_fresh_model_round_trips_reproduces_and_refuses_damage() {
    let tmp = tempfile::tempdir().unwrap();
    for method in [Method::Fsrl, Method::LstmRl] {
        let (core, sim, run) = fresh_core(method);
        let mut model = Model::from_core(&core, &sim, &run).unwrap();
        model.record_check(1000, 3, threads()).unwrap();
        let path = tmp.path().join(format!("{method}.fsrlm"));
        model.save(&path).unwrap();
        let back = Model::load(&path).unwrap();
        same_model(&model, &back);
        // The same values for the same states: the weights are the network.
        assert_eq!(back.run_check(1).unwrap(), model.check);
        assert_reproduces(&back, &path.display().to_string());

        let bytes = std::fs::read(&path).unwrap();
        let damaged = tmp.path().join("damaged.fsrlm");
        let load_err = |b: &[u8]| -> String {
            std::fs::write(&damaged, b).unwrap();
            let e = Model::load(&damaged).expect_err("a damaged model must not load");
            assert!(matches!(e, ModelError::Format { .. }), "{e}");
            e.to_string()
        };
        let mut flipped = bytes.clone();
        flipped[bytes.len() / 3] ^= 0x08;
        assert!(load_err(&flipped).contains("checksum mismatch"));
        assert!(load_err(&bytes[..bytes.len() - 7]).contains("truncated model file"));
        assert!(load_err(&bytes[..12]).contains("truncated model file"));
        let mut other = bytes.clone();
        other[8..12].copy_from_slice(&2u32.to_le_bytes());
        assert!(load_err(&other).contains("model format version 2"));
        // Every single flipped byte anywhere is caught (magic, header, payload or checksum).
        for i in (0..bytes.len())
            .step_by(997)
            .chain([0, 9, 13, bytes.len() - 1])
        {
            let mut b = bytes.clone();
            b[i] ^= 0x80;
            let _ = load_err(&b);
        }
    }
}

#[test]
fn every_command_that_takes_a_checkpoint_takes_a_model_file() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    // A run directory as `fsrl train` leaves it, with an untrained network.
    let (core, sim, run) = fresh_core(Method::Fsrl);
    let run_dir = dir.join("run");
    std::fs::create_dir_all(run_dir.join("checkpoints")).unwrap();
    checkpoint::save(&run_dir.join("checkpoints/latest.ckpt"), &core, &sim, &run).unwrap();

    // export-model: a new directory, atomically, and what it wrote.
    let model_path = dir.join("models/fsrl-env1-invisible-s11.fsrlm");
    let out = ok(&[
        "export-model",
        s(&run_dir),
        "--out",
        s(&model_path),
        "--check-episodes",
        "3",
    ]);
    for want in [
        "method fsrl, sarl network with 96502 parameters",
        "trained on env1-invisible, run seed 11",
        "check: 3 greedy episodes of env1-invisible, seeds 1000..=1002",
        "seed  1002",
    ] {
        assert!(out.contains(want), "{want:?} not in\n{out}");
    }
    let size = std::fs::metadata(&model_path).unwrap().len();
    assert!(out.contains(&format!("({size} bytes")), "{out}");
    assert!(size < 500_000, "{size} bytes is no small model");
    assert!(!dir
        .join("models/fsrl-env1-invisible-s11.fsrlm.tmp")
        .exists());
    let model = Model::load(&model_path).unwrap();
    let mut expected = Model::from_core(&core, &sim, &run).unwrap();
    expected.record_check(1000, 3, 1).unwrap();
    same_model(&model, &expected);
    // Detected by content: the checkpoint under a model's name is still a checkpoint.
    let disguised = dir.join("disguised.fsrlm");
    std::fs::copy(run_dir.join("checkpoints/latest.ckpt"), &disguised).unwrap();
    let (m, kind) = load_policy(&disguised).unwrap();
    assert_eq!(kind, ArtifactKind::Checkpoint);
    assert_eq!(m.net.params(), model.net.params());

    // eval: the report names method, trained setting and seed; its numbers are the check's.
    // Three episodes of env1-invisible, with `extra` flags: the report's one subject.
    let eval_subject = |out: &str, extra: &[&str]| -> serde_json::Value {
        let out = dir.join(out);
        let mut args = vec![
            "eval",
            s(&model_path),
            "--settings",
            "env1-invisible",
            "--episodes",
            "3",
            "--out",
            s(&out),
        ];
        args.extend_from_slice(extra);
        ok(&args);
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
        json["subjects"][0].clone()
    };
    let subj = &eval_subject("ev", &[]);
    assert_eq!(subj["label"], "fsrl (trained env1-invisible, seed 11)");
    assert_eq!(subj["method"], "fsrl");
    assert_eq!(subj["trained_setting"], "env1-invisible");
    assert_eq!(subj["run_seed"], 11);
    assert_eq!(subj["checkpoint"], s(&model_path));
    // Which exact bytes were evaluated (docs/make-pictures.sh and `fsrl reproduce` compare it).
    let sha: String = {
        use sha2::Digest;
        sha2::Sha256::digest(std::fs::read(&model_path).unwrap())
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect()
    };
    assert_eq!(subj["checkpoint_sha256"], sha, "{subj}");
    // Depth-2 planning (Experiment 21): the report says the decisions were planned, the
    // paper's one-step reports do not carry the field; out of range is a clear error.
    assert!(subj.get("planning_top_k").is_none(), "{subj}");
    assert!(subj.get("planning_breadth").is_none(), "{subj}");
    let planned = eval_subject("ev-k3", &["--planning-top-k", "3"]);
    assert_eq!(planned["planning_top_k"], 3);
    assert!(planned.get("planning_breadth").is_none(), "{planned}");
    let narrow = eval_subject(
        "ev-k3m4",
        &["--planning-top-k", "3", "--planning-breadth", "4"],
    );
    assert_eq!(
        (&narrow["planning_top_k"], &narrow["planning_breadth"]),
        (&3.into(), &4.into())
    );
    for flag in ["--planning-top-k", "--planning-breadth"] {
        let e = fails(&["eval", s(&model_path), flag, "82"]);
        assert!(
            e.contains(&format!("{flag} must be in 0..=81, got 82")),
            "{e}"
        );
    }
    // Another crowd (issue 54): the report says which; out of range or among walls: an error.
    let json_of = |out: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join(out).join("eval.json")).unwrap())
            .unwrap()
    };
    assert!(json_of("ev").get("crowd").is_none());
    // The people shield: the report says the decisions had it; the trained default has none.
    assert!(subj.get("shield_s").is_none(), "{subj}");
    let shielded = eval_subject("ev-shield", &["--shield-s", "1.5"]);
    assert_eq!(shielded["shield_s"], 1.5, "{shielded}");
    let crowded = eval_subject("ev-crowd", &["--people", "20", "--crowd", "social-force"]);
    assert_eq!(crowded["settings"][0]["episodes"], 3, "{crowded}");
    assert_eq!(
        json_of("ev-crowd")["crowd"],
        "20 moving people, social-force people"
    );
    for (args, says) in [
        (&["--people", "0"][..], "--people must be in 1..=40, got 0"),
        (
            &["--people", "5", "--settings", "corridor"],
            "corridor places its own",
        ),
        (&["--crowd", "ballet"], "ballet"),
        (
            &["--shield-s=-1"],
            "--shield-s must be in [0, 5] seconds, got -1",
        ),
        (
            &["--shield-s", "NaN"],
            "--shield-s must be in [0, 5] seconds, got NaN",
        ),
    ] {
        let mut a = vec!["eval", s(&model_path), "--episodes", "1"];
        a.extend_from_slice(args);
        let e = fails(&a);
        assert!(e.contains(says), "{e}");
    }
    // `fsrl robustness`: every crowd, one report each, then the table; a second run reuses them.
    let rb = dir.join("rb");
    let table = ok(&[
        "robustness",
        s(&model_path),
        "--episodes",
        "1",
        "--out",
        s(&rb),
    ]);
    assert!(table.contains("| fsrl env1-invisible |"), "{table}");
    for v in lab::robustness::VARIANTS {
        assert!(rb
            .join(v.dir_name())
            .join("env1-invisible/eval.json")
            .is_file());
    }
    let before = std::fs::metadata(rb.join("orca-20/env1-invisible/eval.json"))
        .unwrap()
        .modified()
        .unwrap();
    ok(&[
        "robustness",
        s(&model_path),
        "--episodes",
        "1",
        "--out",
        s(&rb),
    ]);
    let after = std::fs::metadata(rb.join("orca-20/env1-invisible/eval.json"))
        .unwrap()
        .modified()
        .unwrap();
    assert_eq!(before, after, "an up-to-date report is not evaluated again");
    // Another model into the same directory: its rows join the table, the first model's stay
    // (and are not evaluated again).
    let other = dir.join("models/other-s11.fsrlm");
    ok(&[
        "export-model",
        s(&model_path),
        "--out",
        s(&other),
        "--check-episodes",
        "2",
    ]);
    ok(&["robustness", s(&other), "--episodes", "1", "--out", s(&rb)]);
    let report = json_of("rb/orca-20/env1-invisible");
    let checkpoints: Vec<&str> = report["subjects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["checkpoint"].as_str().unwrap())
        .collect();
    assert_eq!(checkpoints, [s(&model_path), s(&other)], "{report}");
    let table: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rb.join("robustness.json")).unwrap())
            .unwrap();
    assert_eq!(table["rows"][0]["cells"][3]["policies"], 2, "{table}");
    let wins = model
        .check
        .iter()
        .filter(|e| e.outcome == Outcome::ReachGoal)
        .count();
    assert_eq!(
        subj["settings"][0]["successes"].as_u64(),
        Some(wins as u64),
        "{subj}"
    );
    let md = std::fs::read_to_string(dir.join("ev").join("eval.md")).unwrap();
    assert!(
        md.contains("trained on env1-invisible (run seed 11)"),
        "{md}"
    );

    // plot episode.
    let pic = dir.join("episode");
    ok(&[
        "plot",
        "episode",
        s(&model_path),
        "--seed",
        "1000",
        "--no-gif",
        "--out",
        s(&pic),
    ]);
    let svg = std::fs::read_to_string(pic.with_extension("svg")).unwrap();
    assert!(
        svg.contains("env1-invisible"),
        "the picture names the setting"
    );

    // The evaluator process, offline.
    let cfg = dir.join("evaluator.toml");
    std::fs::write(&cfg, "[evaluator]\nsettings = [\"env1-invisible\"]\n").unwrap();
    let evo = dir.join("evo");
    let out = ok(&[
        "evaluator",
        "--config",
        s(&cfg),
        "--model",
        s(&model_path),
        "--episodes",
        "3",
        "--out-dir",
        s(&evo),
    ]);
    assert!(
        out.contains("Trained on env1-invisible (run seed 11)"),
        "{out}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(evo.join("report.json")).unwrap()).unwrap();
    let rate = report["settings"][0]["success_rate"].as_f64().unwrap();
    assert!((rate - wins as f64 / 3.0).abs() < 1e-12, "{report}");

    // Damaged model files are clear errors everywhere.
    let bytes = std::fs::read(&model_path).unwrap();
    let bad = dir.join("bad.fsrlm");
    std::fs::write(&bad, &bytes[..bytes.len() / 2]).unwrap();
    let e = fails(&["eval", s(&bad), "--episodes", "1"]);
    assert!(e.contains("bad.fsrlm: truncated model file"), "{e}");
    let mut flipped = bytes.clone();
    flipped[bytes.len() / 2] ^= 1;
    std::fs::write(&bad, &flipped).unwrap();
    let e = fails(&["plot", "episode", s(&bad), "--out", s(&pic)]);
    assert!(e.contains("corrupt model file (checksum mismatch)"), "{e}");
    let e = fails(&["evaluator", "--checkpoint", s(&bad)]);
    assert!(e.contains("bad.fsrlm: corrupt model file"), "{e}");
    let e = fails(&["export-model", s(&bad), "--out", s(&dir.join("x.fsrlm"))]);
    assert!(e.contains("checksum mismatch"), "{e}");
    assert!(!dir.join("x.fsrlm").exists());
}
