//! `fsrl reproduce` end to end on a tiny schedule: one method, one setting, one seed is trained,
//! exported, evaluated and reported beside ORCA; the same command again skips everything; bad
//! names are refused before anything starts; Ctrl-C checkpoints the run being trained and stops
//! the grid so that the same command resumes it.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant, SystemTime};

const TINY: &str = "\
[train]
validation_every_episodes = 0
select = \"last\"
eval_episodes = 2
[train.imitation]
episodes = 5
epochs = 1
[train.rl]
episodes = 3
";

const RUN: &str = "sarl-env2-visible-s0";

fn fsrl(dir: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_fsrl"));
    c.current_dir(dir);
    c
}

/// `fsrl reproduce` of sarl on env2-visible, seed 0, into `dir` (runs/, models/).
fn reproduce(dir: &Path, config: &str, extra: &[&str]) -> Command {
    let mut c = fsrl(dir);
    c.args([
        "reproduce",
        "--config",
        config,
        "--methods",
        "sarl",
        "--settings",
        "env2-visible",
        "--seeds",
        "0",
        "--runs",
        "runs",
        "--models",
        "models",
        "--episodes",
        "2",
    ])
    .args(extra);
    c
}

fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn mtime(p: &Path) -> SystemTime {
    std::fs::metadata(p)
        .and_then(|m| m.modified())
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
fn a_tiny_grid_is_trained_exported_evaluated_reported_and_then_skipped() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("tiny.toml"), TINY).unwrap();

    // The plan alone touches nothing.
    let o = reproduce(dir, "tiny.toml", &["--dry-run"])
        .output()
        .unwrap();
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains(&format!("{RUN}  new")), "{stdout}");
    assert!(
        stdout.contains("1 runs: 0 finished, 0 to resume, 1 to train"),
        "{stdout}"
    );
    assert!(!dir.join("runs").exists() && !dir.join("models").exists());

    // Every subcommand the grid runs exists (a failing help is a failure, not a reason to skip).
    for sub in ["train", "export-model", "eval", "compare"] {
        let help = fsrl(dir).args([sub, "--help"]).output().unwrap();
        assert!(
            help.status.success(),
            "fsrl {sub} --help: {}",
            String::from_utf8_lossy(&help.stderr)
        );
    }

    let o = reproduce(dir, "tiny.toml", &[]).output().unwrap();
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    let run = dir.join("runs").join(RUN);
    // Trained by the distributed system (the default): a learner, actors and an evaluator.
    let mode = json(&run.join("run.json"));
    assert_eq!(mode["mode"], "distributed", "{mode}");
    assert_eq!(mode["actors"], 2, "{mode}");
    let model = dir.join("models").join(format!("{RUN}.fsrlm"));
    let eval = dir.join("runs/eval").join(RUN).join("eval.json");
    let orca = dir.join("runs/eval/orca/eval.json");
    let report = dir.join("runs/report");
    for f in [
        run.join("report.json"),
        model.clone(),
        eval.clone(),
        orca.clone(),
        report.join("compare.md"),
        report.join("compare.csv"),
        report.join("compare.json"),
    ] {
        assert!(f.is_file(), "missing {}\n{stderr}", f.display());
    }
    assert!(
        stderr.contains(&format!("[1/1] {RUN}: training, new")),
        "{stderr}"
    );
    assert!(
        stderr.contains("1/1 runs complete, grid ETA 0s"),
        "{stderr}"
    );
    // The model is evaluated on its own setting only; ORCA on all six.
    let e = json(&eval);
    assert_eq!(e["episodes_per_setting"], 2);
    assert_eq!(e["subjects"][0]["method"], "sarl");
    assert_eq!(e["subjects"][0]["settings"].as_array().unwrap().len(), 1);
    assert_eq!(e["subjects"][0]["settings"][0]["setting"], "env2-visible");
    assert_eq!(
        json(&orca)["subjects"][0]["settings"]
            .as_array()
            .unwrap()
            .len(),
        6
    );
    // One report beside the paper's numbers, printed too.
    let md = std::fs::read_to_string(report.join("compare.md")).unwrap();
    for needle in [
        "| sarl (n=1) |",
        "| orca (n=1) |",
        "| SARL (paper) | 12.25 |",
    ] {
        assert!(md.contains(needle), "missing {needle:?} in\n{md}");
        assert!(stdout.contains(needle), "missing {needle:?} in stdout");
    }
    let methods: Vec<String> = json(&report.join("compare.json"))["groups"]
        .as_array()
        .unwrap()
        .iter()
        .map(|g| g["method"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(methods, ["orca", "sarl"]);

    // The same command again skips every step and writes the report again.
    let stamps: Vec<(PathBuf, SystemTime)> = [run.join("report.json"), model, eval, orca]
        .into_iter()
        .map(|p| {
            let t = mtime(&p);
            (p, t)
        })
        .collect();
    std::fs::remove_dir_all(&report).unwrap();
    let o = reproduce(dir, "tiny.toml", &[]).output().unwrap();
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(
        stderr.contains(&format!("{RUN}: finished, exported and evaluated; skipped")),
        "{stderr}"
    );
    for needle in ["training,", "exporting", "evaluating"] {
        assert!(!stderr.contains(needle), "{needle:?} in\n{stderr}");
    }
    for (p, t) in stamps {
        assert_eq!(mtime(&p), t, "{} was written again", p.display());
    }
    assert!(std::fs::read_to_string(report.join("compare.md"))
        .unwrap()
        .contains("| sarl (n=1) |"));
    let o = reproduce(dir, "tiny.toml", &["--dry-run"])
        .output()
        .unwrap();
    let (stdout, _) = text(&o);
    assert!(
        stdout.contains("1 runs: 1 finished, 0 to resume, 0 to train; 0 to export, 0 to evaluate"),
        "{stdout}"
    );

    // A failing step stops the grid with an error naming the run and its directory (here the
    // model's path is taken by a directory, so the export cannot write it).
    let model = dir.join("models").join(format!("{RUN}.fsrlm"));
    std::fs::remove_file(&model).unwrap();
    std::fs::create_dir(&model).unwrap();
    let o = reproduce(dir, "tiny.toml", &[]).output().unwrap();
    let (_, stderr) = text(&o);
    assert!(!o.status.success());
    // The child's own error comes first, ours last.
    let error = stderr
        .lines()
        .rfind(|l| l.starts_with("error:"))
        .unwrap_or("");
    assert!(
        error.contains(&format!("[1/1] {RUN}: exporting the model failed"))
            && error.contains(&format!("its directory: runs/{RUN}")),
        "{stderr}"
    );
}

#[test]
fn bad_names_are_refused_before_anything_starts() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("tiny.toml"), TINY).unwrap();
    let o = fsrl(dir)
        .args([
            "reproduce",
            "--config",
            "tiny.toml",
            "--methods",
            "sarl,dqn",
            "--settings",
            "env2-visible,env9-visible",
            "--runs",
            "runs",
            "--models",
            "models",
        ])
        .output()
        .unwrap();
    let (_, stderr) = text(&o);
    assert!(!o.status.success());
    for needle in [
        "2 problems",
        "unknown method `dqn`",
        "unknown setting `env9-visible`",
    ] {
        assert!(stderr.contains(needle), "missing {needle:?} in\n{stderr}");
    }
    assert!(!dir.join("runs").exists() && !dir.join("models").exists());
}

/// Issue 44: a bad `--replay-ratio` is refused with one line before anything starts (it used to
/// pass the grid's check and start ORCA's evaluation and the first run first).
#[test]
fn a_bad_replay_ratio_is_refused_before_anything_starts() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(dir.join("tiny.toml"), TINY).unwrap();
    for bad in ["5,1", "-1,4", "nan", "0,0", "inf"] {
        let o = reproduce(dir, "tiny.toml", &["--replay-ratio", bad])
            .output()
            .unwrap();
        let (_, stderr) = text(&o);
        assert!(!o.status.success(), "{bad}: {stderr}");
        let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("error")).collect();
        assert!(
            errors.len() == 1 && errors[0].contains("--replay-ratio"),
            "{bad}: one line naming the flag:\n{stderr}"
        );
        assert!(
            !dir.join("runs").exists() && !dir.join("models").exists(),
            "{bad}: something started"
        );
    }
}

#[test]
fn ctrl_c_checkpoints_the_run_in_training_and_the_same_command_resumes_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    std::fs::write(
        dir.join("long.toml"),
        TINY.replace("episodes = 3", "episodes = 100000"),
    )
    .unwrap();
    // In one process (the bit-exact path), so that it can run beside the distributed test.
    let mut child = reproduce(dir, "long.toml", &["--single-process"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = pipe.read_to_string(&mut s);
        s
    });
    // Ready when the first RL episode is logged.
    let metrics = dir.join("runs").join(RUN).join("metrics.jsonl");
    let deadline = Instant::now() + Duration::from_secs(180);
    while !std::fs::read_to_string(&metrics)
        .unwrap_or_default()
        .contains("\"phase\":\"rl\"")
    {
        assert!(Instant::now() < deadline, "no RL episode within 180 s");
        assert!(child.try_wait().unwrap().is_none(), "exited early");
        std::thread::sleep(Duration::from_millis(50));
    }
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let status = child.wait().unwrap();
    let stderr = reader.join().unwrap();
    assert_eq!(status.code(), Some(130), "{stderr}");
    assert!(stderr.contains("run the same command again"), "{stderr}");
    let run = dir.join("runs").join(RUN);
    assert!(run.join("checkpoints/latest.ckpt").is_file(), "{stderr}");
    assert!(!run.join("report.json").exists());
    let o = reproduce(dir, "long.toml", &["--dry-run"])
        .output()
        .unwrap();
    let (stdout, _) = text(&o);
    assert!(stdout.contains(&format!("{RUN}  resume (")), "{stdout}");
    assert!(stdout.contains("1 to resume"), "{stdout}");
}

/// `--shard I/N`: two shards as two processes at once cover a small grid exactly once, and the
/// report that `--no-train` then writes over their shared directories is the one the unsharded
/// grid writes (single-process training: the same runs, bit for bit).
#[test]
fn two_shards_cover_the_grid_once_and_their_report_is_the_unsharded_one() {
    let tmp = tempfile::tempdir().unwrap();
    let (sharded, whole) = (tmp.path().join("sharded"), tmp.path().join("whole"));
    let grid = |dir: &Path, extra: &[&str]| -> Command {
        std::fs::create_dir_all(dir).unwrap();
        std::fs::write(dir.join("tiny.toml"), TINY).unwrap();
        let mut c = fsrl(dir);
        c.args(["reproduce", "--config", "tiny.toml", "--single-process"])
            .args(["--methods", "sarl,lstm-rl", "--settings", "env2-visible"])
            .args(["--seeds", "0,1", "--runs", "runs", "--models", "models"])
            .args(["--episodes", "2"])
            .args(extra)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .env_remove("JOB_COMPLETION_INDEX");
        c
    };
    let shards: Vec<_> = ["0/2", "1/2"]
        .iter()
        .map(|s| {
            grid(&sharded, &["--shard", s])
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    let mut trained = Vec::new();
    for child in shards {
        let o = child.wait_with_output().unwrap();
        let (_, stderr) = text(&o);
        assert!(o.status.success(), "{stderr}");
        assert!(stderr.contains("done:"), "{stderr}");
        trained.extend(
            stderr
                .lines()
                .filter(|l| l.contains(": training, new"))
                .map(|l| {
                    l.split(": ")
                        .next()
                        .unwrap()
                        .split(' ')
                        .nth(1)
                        .unwrap()
                        .to_string()
                }),
        );
    }
    trained.sort();
    assert_eq!(
        trained,
        [
            "lstm-rl-env2-visible-s0",
            "lstm-rl-env2-visible-s1",
            "sarl-env2-visible-s0",
            "sarl-env2-visible-s1"
        ],
        "every run trained by exactly one shard"
    );
    assert!(
        !sharded.join("runs/report").exists(),
        "a shard writes no report"
    );
    let o = grid(&sharded, &["--no-train"]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o).1);
    let o = grid(&whole, &[]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o).1);
    for f in ["compare.md", "compare.csv"] {
        let a = std::fs::read_to_string(sharded.join("runs/report").join(f)).unwrap();
        let b = std::fs::read_to_string(whole.join("runs/report").join(f)).unwrap();
        assert_eq!(a, b, "{f} differs");
    }
    // A bad shard is refused before anything starts.
    let o = grid(&tmp.path().join("bad"), &["--shard", "2/2"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(text(&o).1.contains("--shard 2/2"), "{}", text(&o).1);
    assert!(!tmp.path().join("bad/runs").exists());
}
