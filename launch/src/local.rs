//! A distributed run on one machine (`fsrl train`'s default mode): a learner, N actors and an
//! evaluator as child processes of the fsrl executable, on the iceoryx2 data plane (or zenoh)
//! with zenoh on loopback for metrics and liveliness. No router, no set-up. Progress comes from
//! the live metrics; a stop (the caller's flag, set on Ctrl-C) stops every child cleanly (the
//! learner checkpoints), and the same run with `resume` goes on. Every process's metrics go to
//! `processes.jsonl`, the learning curve into `metrics.jsonl`, the timing into `run.json`.

use std::fs::File;
use std::io::Write;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use proto::{keys, Role, SenderId};
use transport::{DataPlane, Transport};

use lab::evaluation::final_evaluation;
use lab::run::{distributed_summary, RunTiming};

use crate::config::{run_checkpoint, Resolved};

/// The data plane as `fsrl train --transport` names it.
fn plane_name(p: DataPlane) -> &'static str {
    match p {
        DataPlane::Zenoh => "zenoh",
        DataPlane::Iceoryx2 => "iceoryx2",
    }
}

/// zenoh's usual port when it is free, else any free loopback port.
fn learner_port() -> anyhow::Result<u16> {
    if TcpListener::bind("127.0.0.1:7447").is_ok() {
        return Ok(7447);
    }
    let l = TcpListener::bind("127.0.0.1:0").context("cannot find a free loopback port")?;
    Ok(l.local_addr()?.port())
}

struct Children {
    list: Vec<(String, Child)>,
}

impl Children {
    fn signal(&self, sig: i32) {
        for (_, c) in &self.list {
            // SAFETY: kill(2) on the pid of a child we spawned and have not reaped.
            unsafe {
                libc::kill(c.id() as libc::pid_t, sig);
            }
        }
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        for (_, c) in &mut self.list {
            if let Ok(None) = c.try_wait() {
                let _ = c.kill();
                let _ = c.wait();
            }
        }
    }
}

fn spawn(exe: &Path, role: &str, args: &[String], logs: &Path) -> anyhow::Result<Child> {
    let log = File::create(logs.join(format!("{role}.log")))
        .with_context(|| format!("cannot create {}/{role}.log", logs.display()))?;
    let mut cmd = Command::new(exe);
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(log.try_clone()?)
        .stderr(log);
    // Children ignore the terminal's Ctrl-C; this process forwards it to them.
    // SAFETY: setpgid in the child before exec only changes its process group.
    unsafe {
        std::os::unix::process::CommandExt::pre_exec(&mut cmd, || {
            libc::setpgid(0, 0);
            Ok(())
        });
    }
    cmd.spawn()
        .with_context(|| format!("cannot start the {role} process"))
}

/// Appends what `validation.jsonl` gained after byte `start` to the metrics log.
fn copy_validation(path: &Path, start: u64, log: &mut File) -> anyhow::Result<()> {
    let Ok(bytes) = std::fs::read(path) else {
        return Ok(());
    };
    let new = bytes.get(start as usize..).unwrap_or_default();
    for line in String::from_utf8_lossy(new).lines() {
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("a broken line in {}", path.display()))?;
        writeln!(log, "{v}")?;
    }
    Ok(())
}

/// The `phase = "validation"` line of `metrics.jsonl` (the same fields as `fsrl train
/// --single-process` writes) from an evaluator's metrics message, if it is a validation point.
fn validation_line(m: &proto::Metrics) -> Option<serde_json::Value> {
    let v = &m.values;
    let get = |k: &str| v.get(&format!("validation_{k}")).copied();
    Some(serde_json::json!({
        "phase": "validation",
        "episode": get("episode")? as u64,
        "episodes": get("episodes")? as u64,
        "success_rate": get("success_rate")?,
        "collision_rate": get("collision_rate")?,
        "timeout_rate": get("timeout_rate")?,
        "discomfort": get("discomfort")?,
        "nav_time_s": get("nav_time_s"),
        "mean_return": get("mean_return")?,
        "wall_s": m.wall_time_s,
    }))
}

/// The updates per RL episode the learner realised: its final counters (the checkpoint it wrote
/// at the end) from where it started counting, which every metrics message of its training
/// names (`rl_start_episodes`, `rl_start_updates`: a resumed run counts from its checkpoint).
/// `None` when `learner` names no start (a learner that never reached training).
fn realised_ratio(out: &Path, learner: &proto::Metrics) -> anyhow::Result<Option<f64>> {
    let (Some(e0), Some(u0)) = (
        learner.values.get("rl_start_episodes"),
        learner.values.get("rl_start_updates"),
    ) else {
        return Ok(None);
    };
    let path = out.join("checkpoints").join("latest.ckpt");
    let c = learner::checkpoint::load(&path)
        .with_context(|| format!("cannot read {}", path.display()))?
        .core
        .counters();
    let episodes = c.rl_episodes.saturating_sub(*e0 as u64);
    let updates = c.updates.saturating_sub(*u0 as u64);
    Ok(Some(if episodes == 0 {
        0.0
    } else {
        updates as f64 / episodes as f64
    }))
}

/// Puts the realised replay ratio of the learner's final counters ([`realised_ratio`]) in its
/// newest metrics, for the summary and `run.json`: not the value of whichever of its metrics
/// messages arrived last (its last rounds of updates come after the last episode).
fn use_final_ratio(out: &Path, last: &mut std::collections::BTreeMap<String, proto::Metrics>) {
    let Some((_, m)) = last.iter_mut().find(|(k, _)| k.starts_with("learner")) else {
        return;
    };
    match realised_ratio(out, m) {
        Ok(Some(r)) => {
            m.values.insert("updates_per_episode".into(), r);
        }
        Ok(None) => {}
        Err(e) => eprintln!("warning: the realised replay ratio is not known: {e:#}"),
    }
}

/// What to launch.
pub struct Launch {
    /// The fsrl executable: its `learner`, `actor` and `evaluator` subcommands are the processes.
    pub exe: PathBuf,
    /// The run's configuration (validated); the launcher sets the run id, loopback endpoints,
    /// the data plane and the directories, and writes it as the run's `config.toml`.
    pub resolved: Resolved,
    /// The run directory.
    pub out: PathBuf,
    /// Continue the run in `out` from its last checkpoint.
    pub resume: bool,
    /// Actor processes (at least one).
    pub actors: u32,
    pub data_plane: DataPlane,
    /// Start the evaluator process (validations, kept snapshots).
    pub evaluator: bool,
    /// Test episodes per setting of the evaluator's own reports.
    pub eval_episodes: Option<u32>,
    /// Serve the run's live page on this port of 127.0.0.1 (`fsrl dashboard`, a child process).
    pub dashboard: Option<u16>,
    /// Keep the run's TensorBoard files (`tb/`) in step with its logs and live metrics.
    pub tensorboard: bool,
}

/// Runs the processes to the end of the schedule (or until `stop` is set), then the final
/// evaluation of the run's policy; prints progress on stderr and the summary on stdout.
pub fn run(launch: Launch, stop: &AtomicBool) -> anyhow::Result<()> {
    let Launch {
        exe,
        mut resolved,
        out,
        resume,
        actors,
        data_plane,
        evaluator,
        eval_episodes,
        dashboard,
        tensorboard,
    } = launch;
    if actors == 0 {
        bail!("a distributed run needs at least one actor");
    }
    run_checkpoint(&out, resume)?;
    let logs = out.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;

    // The run's config: loopback endpoints, the learner listening on a free port.
    let port = learner_port()?;
    let learner_ep = format!("tcp/127.0.0.1:{port}");
    let f = &mut resolved.file;
    f.run.id = out
        .file_name()
        .map(|n| {
            n.to_string_lossy()
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                        c
                    } else {
                        '_'
                    }
                })
                .collect()
        })
        .unwrap_or_else(|| "local".to_string());
    f.transport.data_plane = data_plane;
    f.transport.zenoh.multicast_scouting = false;
    f.transport.zenoh.connect = Vec::new();
    f.transport.zenoh.listen = vec!["tcp/127.0.0.1:0".into()];
    f.learner.run_dir = Some(out.clone());
    f.evaluator.out_dir = Some(out.clone());
    f.evaluator.threads = 1;
    // The launcher evaluates the run's chosen policy itself at the end, as `--single-process`.
    f.evaluator.final_report = false;
    if let Some(n) = eval_episodes {
        f.evaluator.episodes_per_setting = n;
    }
    let cfg_path = out.join("config.toml");
    std::fs::write(&cfg_path, toml::to_string(&resolved.file)?)
        .with_context(|| format!("cannot write {}", cfg_path.display()))?;
    let cfg_arg = cfg_path.to_string_lossy().to_string();
    let mut children = Children { list: Vec::new() };
    // The learner listens on the known port; every other process connects to it.
    let learner_args = vec![
        "learner".to_string(),
        "--config".into(),
        cfg_arg.clone(),
        "--listen".into(),
        learner_ep.clone(),
    ];
    children.list.push((
        "learner".into(),
        spawn(&exe, "learner", &learner_args, &logs)?,
    ));
    for id in 0..actors {
        let a = vec![
            "actor".to_string(),
            "--config".into(),
            cfg_arg.clone(),
            "--id".into(),
            id.to_string(),
            "--connect".into(),
            learner_ep.clone(),
        ];
        children.list.push((
            format!("actor-{id}"),
            spawn(&exe, &format!("actor-{id}"), &a, &logs)?,
        ));
    }
    if evaluator {
        let e = vec![
            "evaluator".to_string(),
            "--config".into(),
            cfg_arg.clone(),
            "--every".into(),
            "0".into(),
            "--connect".into(),
            learner_ep.clone(),
        ];
        children
            .list
            .push(("evaluator".into(), spawn(&exe, "evaluator", &e, &logs)?));
    }
    eprintln!(
        "training {} on {} in {} with {} actor process(es) over {} (learner at {learner_ep}); logs in {}",
        resolved.method,
        resolved.setting,
        out.display(),
        actors,
        plane_name(data_plane),
        logs.display()
    );
    eprintln!(
        "live metrics from another terminal: fsrl watch --connect {learner_ep} --run {}",
        resolved.file.run.id
    );
    // The live page: its own process (killed with the others at the end), reading the run's
    // metrics as `fsrl dashboard` does anywhere.
    let mut page = Children { list: Vec::new() };
    if let Some(port) = dashboard {
        let d = vec![
            "dashboard".to_string(),
            "--connect".into(),
            learner_ep.clone(),
            "--run".into(),
            resolved.file.run.id.clone(),
            "--port".into(),
            port.to_string(),
        ];
        page.list
            .push(("dashboard".into(), spawn(&exe, "dashboard", &d, &logs)?));
        eprintln!("live page: http://127.0.0.1:{port}/");
    }

    // Watch the run's metrics like any other tool would.
    let mut tcfg = resolved
        .file
        .transport
        .for_sender(&resolved.file.run.id, SenderId::new(Role::Monitor, 0))?;
    tcfg.data_plane = DataPlane::Zenoh;
    tcfg.zenoh.connect = vec![learner_ep.clone()];
    let monitor = Transport::open(tcfg)?;
    let metrics = monitor.subscriber(&keys::all_metrics(monitor.run()))?;
    // Every process's live metrics, one line each (the learner writes the training log,
    // metrics.jsonl, itself).
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(out.join("processes.jsonl"))
        .context("cannot open processes.jsonl")?;
    // The evaluator appends the learning curve to validation.jsonl; what this invocation adds
    // is copied into metrics.jsonl at the end, once the learner has stopped writing it.
    let validation_path = out.join("validation.jsonl");
    let validation_start = std::fs::metadata(&validation_path).map_or(0, |m| m.len());
    // TensorBoard files in out/tb/: the logs as they grow, the learner's live-only values.
    let mut board = tensorboard.then(|| tboard::Keeper::open(&out, tboard::Mode::Distributed));
    let total = resolved.file.train.rl.episodes;
    let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr_with_hz(4));
    bar.set_style(
        ProgressStyle::with_template(
            "{prefix:>9} [{elapsed_precise}] {bar:30} {pos}/{len} (ETA {eta}) {msg}",
        )
        .expect("template"),
    );
    bar.set_prefix("starting");
    let mut last_plain = Instant::now();
    let started = Instant::now();
    // The newest metrics of each process, and when the learner's warm start ended (its clock).
    let mut last_values: std::collections::BTreeMap<String, proto::Metrics> = Default::default();
    let mut warm_start_s: Option<f64> = None;
    let learner_exit = loop {
        if stop.load(Ordering::SeqCst) {
            children.signal(libc::SIGINT);
        }
        let (_, learner) = &mut children.list[0];
        if let Some(status) = learner.try_wait()? {
            break status;
        }
        if let Some(b) = &mut board {
            b.tick();
        }
        if let Some(msg) = metrics.recv_timeout(Duration::from_millis(200))? {
            let sender = msg.header.sender.to_string();
            let line = serde_json::json!({ "sender": sender, "wall_s": msg.body.wall_time_s, "env_steps": msg.body.env_steps, "episodes": msg.body.episodes, "values": msg.body.values});
            let _ = writeln!(log, "{line}");
            last_values.insert(sender, msg.body.clone());
            if let Some(b) = &mut board {
                b.live(msg.header.sender, &msg.body);
            }
            if msg.header.sender.role == Role::Evaluator {
                // A point of the learning curve; it reaches metrics.jsonl from the evaluator's
                // validation.jsonl when the run ends (this live copy is best effort).
                if let Some(line) = validation_line(&msg.body) {
                    bar.println(format!(
                        "validation after {} RL episodes: success {:.2}, collision {:.2}, Disc. {:.3}",
                        line["episode"], line["success_rate"].as_f64().unwrap_or(f64::NAN),
                        line["collision_rate"].as_f64().unwrap_or(f64::NAN),
                        line["discomfort"].as_f64().unwrap_or(f64::NAN)
                    ));
                }
                continue;
            }
            if msg.header.sender.role != Role::Learner {
                continue;
            }
            let v = &msg.body.values;
            let get = |k: &str| v.get(k).copied().unwrap_or(0.0);
            if warm_start_s.is_none() && get("imitation_done") > 0.5 {
                warm_start_s = Some(msg.body.wall_time_s);
            }
            if get("imitation_done") < 0.5 && v.contains_key("demo_target") {
                bar.set_prefix("demos");
                bar.set_message(format!("{}/{}", get("demo_episodes"), get("demo_target")));
            } else if v.contains_key("imitation_epoch") {
                bar.set_prefix("imitation");
                bar.set_message(format!(
                    "epoch {}/{} loss {:.5}",
                    get("imitation_epoch"),
                    get("imitation_epochs"),
                    get("loss")
                ));
            } else if v.contains_key("episodes") && get("imitation_done") > 0.5 {
                bar.set_prefix("rl");
                bar.set_position(get("episodes") as u64);
                bar.set_message(format!(
                    "ε {:.3} success {:.2} loss {:.5} {:.2} ep/s actors {} lag {:.1}",
                    get("epsilon"),
                    get("success_rate"),
                    get("loss"),
                    get("episodes_per_s"),
                    get("actors_alive"),
                    get("policy_lag_mean")
                ));
            }
            if bar.is_hidden() && last_plain.elapsed() >= Duration::from_secs(10) {
                last_plain = Instant::now();
                eprintln!(
                    "{} {}/{} {}",
                    bar.prefix(),
                    bar.position(),
                    total,
                    bar.message()
                );
            }
        }
    };
    bar.finish_and_clear();
    // Metrics still queued or in flight when the learner exited (under load its last messages,
    // or all of a short run's, can be): take them before the summary reads each process's
    // last, so that run.json always has the learner's figures. Until 100 ms pass without one,
    // at most 2 s.
    let drain_until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < drain_until {
        let Some(msg) = metrics.recv_timeout(Duration::from_millis(100))? else {
            break;
        };
        let sender = msg.header.sender.to_string();
        let line = serde_json::json!({ "sender": sender, "wall_s": msg.body.wall_time_s, "env_steps": msg.body.env_steps, "episodes": msg.body.episodes, "values": msg.body.values});
        let _ = writeln!(log, "{line}");
        if let Some(b) = &mut board {
            b.live(msg.header.sender, &msg.body);
        }
        last_values.insert(sender, msg.body);
    }
    // The learner is done: actors and the evaluator finish on their own (the evaluator after the
    // final evaluation); after a stop, they are told to stop too.
    let interrupted = stop.load(Ordering::SeqCst) || !learner_exit.success();
    if interrupted {
        children.signal(libc::SIGINT);
    }
    let mut failed = Vec::new();
    if !learner_exit.success() {
        failed.push(format!("learner ({learner_exit})"));
    }
    // An actor or evaluator that started after a short run's learner had already finished
    // waits for a learner that never comes: once an actor could have left (a finished run's
    // actors leave at once) or the evaluator finished a last validation, it is told to stop.
    let waited_from = Instant::now();
    for (name, child) in children.list.iter_mut().skip(1) {
        let mut deadline =
            Instant::now() + Duration::from_secs(if interrupted { 20 } else { 3600 });
        let grace = Duration::from_secs(if name.starts_with("actor") { 30 } else { 600 });
        let mut told = false;
        loop {
            if let Some(s) = child.try_wait()? {
                if told {
                    failed.push(format!(
                        "{name} (still waiting for the learner {} s after it finished; stopped)",
                        grace.as_secs()
                    ));
                } else if !s.success() && !interrupted {
                    failed.push(format!("{name} ({s})"));
                }
                break;
            }
            if !interrupted && !told && waited_from.elapsed() > grace {
                told = true;
                deadline = deadline.min(Instant::now() + Duration::from_secs(20));
                // SAFETY: signalling our own child.
                unsafe {
                    libc::kill(child.id() as libc::pid_t, libc::SIGINT);
                }
            }
            if Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                failed.push(format!("{name} (did not exit; killed)"));
                break;
            }
            if stop.load(Ordering::SeqCst) {
                // SAFETY: signalling our own child.
                unsafe {
                    libc::kill(child.id() as libc::pid_t, libc::SIGINT);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    let copied = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(out.join("metrics.jsonl"))
        .context("cannot open metrics.jsonl")
        .and_then(|mut m| copy_validation(&validation_path, validation_start, &mut m));
    if let Err(e) = copied {
        eprintln!("warning: the learning curve did not reach metrics.jsonl: {e:#}");
    }
    if let Some(b) = &mut board {
        b.finish();
    }
    if !learner_exit.success() {
        bail!(
            "processes failed: {} (see {})",
            failed.join(", "),
            logs.display()
        );
    }
    if !failed.is_empty() {
        // The learner finished the schedule: the run is complete; what the others missed (an
        // actor's episodes, the evaluator's later validations) is said, not fatal.
        eprintln!(
            "warning: the learner finished, but processes failed: {} (see {})",
            failed.join(", "),
            logs.display()
        );
    }
    if interrupted {
        eprintln!(
            "stopped; the learner checkpointed in {}. Continue with the same command and --resume",
            out.display()
        );
        return Ok(());
    }
    let rl_end_s = started.elapsed().as_secs_f64();
    let final_start = Instant::now();
    final_evaluation(&out, &resolved.spec())?;
    let mut timing = RunTiming::read(&out, "distributed");
    timing.set("actors", actors);
    timing.set("transport", plane_name(data_plane));
    // The schedule of updates: the adaptive bounds, or the fixed count per episode.
    timing.set(
        "replay_ratio",
        match resolved.file.train.rl.replay_ratio {
            Some(r) => serde_json::json!({ "min": r.min, "max": r.max }),
            None => serde_json::json!(format!(
                "fixed {}",
                resolved.file.train.rl.batches_per_episode
            )),
        },
    );
    let warm = warm_start_s.unwrap_or(0.0);
    timing.add_s("warm_start_s", warm);
    timing.add_s("rl_s", (rl_end_s - warm).max(0.0));
    timing.add_s("final_evaluation_s", final_start.elapsed().as_secs_f64());
    timing.add_s("total_s", started.elapsed().as_secs_f64());
    use_final_ratio(&out, &mut last_values);
    let summary = distributed_summary(&last_values, &mut timing);
    timing.write(&out)?;
    let report = out.join("report.md");
    if let Ok(mut md) = std::fs::read_to_string(&report) {
        md.push_str(&summary);
        std::fs::write(&report, &md)
            .with_context(|| format!("cannot write {}", report.display()))?;
    }
    println!("{summary}");
    println!(
        "run directory: {} (config.toml, run.json, checkpoints/, metrics.jsonl, processes.jsonl, report.md, logs/)",
        out.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use policy::method::{Method, TrainConfig};
    use policy::rollout::{rollout, Behaviour};

    /// Issue 44: the realised ratio of `run.json` is the learner's final counters from where its
    /// training started, whatever its newest metrics message said (here a stale one).
    #[test]
    fn the_realised_ratio_comes_from_the_final_counters() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = sim::SimConfig::default();
        let mut core = learner::LearnerCore::new(
            Method::Sarl,
            TrainConfig::default(),
            cfg.humans.count,
            cfg.dt_s,
            1,
        )
        .unwrap();
        let mut env = sim::Env::new(cfg.clone(), "env1-invisible".parse().unwrap(), 0).unwrap();
        let mut episode = |seed| {
            let orca = Behaviour::Orca {
                safety_space_m: 0.0,
            };
            rollout(&mut env, seed, orca).unwrap()
        };
        for seed in 0..2 {
            core.add_episode(&episode(seed), true).unwrap();
        }
        core.imitation(1, |_, _| {}).unwrap();
        core.start_rl().unwrap();
        let start = core.counters().updates;
        for seed in 10..12 {
            core.add_episode(&episode(seed), false).unwrap();
        }
        core.train_round(3).unwrap();
        core.train_round(4).unwrap();
        assert_eq!(core.counters().updates - start, 7);
        let run = learner::checkpoint::RunInfo {
            run_id: "r".into(),
            setting: "env1-invisible".into(),
            run_seed: 1,
            accepted_below: Default::default(),
        };
        std::fs::create_dir_all(dir.path().join("checkpoints")).unwrap();
        let ckpt = dir.path().join("checkpoints").join("latest.ckpt");
        learner::checkpoint::save(&ckpt, &core, &cfg, &run).unwrap();
        // The newest message to arrive, from before the last round.
        let mut m = proto::Metrics::default();
        for (k, v) in [
            ("updates_per_episode", 1.5),
            ("rl_start_episodes", 0.0),
            ("rl_start_updates", start as f64),
        ] {
            m.values.insert(k.into(), v);
        }
        let mut last = std::collections::BTreeMap::from([("learner-0".to_string(), m)]);
        use_final_ratio(dir.path(), &mut last);
        assert_eq!(last["learner-0"].values["updates_per_episode"], 3.5);
    }
}
