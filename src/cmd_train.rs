//! `fsrl train`: trains one method on one setting in one process (imitation from the ORCA
//! demonstrator, then deep V-learning), with progress, checkpoints, a metrics log, Ctrl-C
//! handling, `--resume`, and a final evaluation on the setting's test seeds.

use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use evaluator::{evaluate, Subject};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use learner::checkpoint::{self, RunInfo};
use learner::model::Model;
use learner::LearnerCore;
use policy::lookahead::Lookahead;
use policy::method::{RunSpec, Select};
use policy::rollout::{episode_seed, rollout, Behaviour};
use serde::Serialize;
use sim::{Env, Outcome};

use crate::config::{run_checkpoint, Resolved, RunOverrides};
use crate::report::{Report, SettingReport};

/// The final evaluation of a finished run, the same in both modes: the run's policy (its
/// `train.select` rule: the last checkpoint, or the chosen validation snapshot) on
/// `train.eval_episodes` test episodes of its own setting; writes `report.json` and `report.md`
/// into the run directory and prints the table.
pub(crate) fn final_evaluation(out: &Path, spec: &RunSpec) -> anyhow::Result<Report> {
    let train = &spec.train;
    eprintln!(
        "evaluating on {} test episodes of {} ...",
        train.eval_episodes, spec.setting
    );
    let path = select::run_policy(out, None)?;
    let (model, _) = learner::model::load_policy(&path)
        .with_context(|| format!("cannot load {}", path.display()))?;
    let subject = Subject::of_run(spec, &model.net);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let results = evaluate(
        subject,
        &spec.sim,
        &[spec.setting],
        train.test_seed_start,
        train.eval_episodes,
        threads,
    )?;
    let report = Report {
        method: spec.method.name().to_string(),
        policy_version: model.counters.policy_version,
        test_seed_start: train.test_seed_start,
        settings: results
            .iter()
            .map(|r| SettingReport::new(r.setting.name(), &r.aggregate))
            .collect(),
    };
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    let md = report.markdown();
    std::fs::write(out.join("report.md"), &md)?;
    println!("{md}");
    Ok(report)
}

/// `run.json` of a run directory: which mode trained it and where its wall-clock time went
/// (seconds; in a distributed run also each process's waiting and the realised replay ratio).
pub(crate) struct RunTiming {
    value: serde_json::Map<String, serde_json::Value>,
}

impl RunTiming {
    pub(crate) fn new(mode: &str) -> Self {
        let mut value = serde_json::Map::new();
        value.insert("mode".into(), mode.into());
        Self { value }
    }
    pub(crate) fn set(&mut self, key: &str, v: impl Into<serde_json::Value>) {
        self.value.insert(key.into(), v.into());
    }
    /// Adds `key` to the recorded time (a resumed run adds its invocation's share).
    pub(crate) fn add_s(&mut self, key: &str, seconds: f64) {
        let before = self.value.get(key).and_then(|v| v.as_f64()).unwrap_or(0.0);
        self.set(key, before + seconds);
    }
    /// What an earlier invocation of the same run recorded (a resumed run goes on from it).
    pub(crate) fn read(out: &Path, mode: &str) -> Self {
        let mut t = Self::new(mode);
        if let Ok(text) = std::fs::read_to_string(out.join("run.json")) {
            if let Ok(serde_json::Value::Object(m)) = serde_json::from_str(&text) {
                if m.get("mode").and_then(|v| v.as_str()) == Some(mode) {
                    t.value = m;
                }
            }
        }
        t
    }
    pub(crate) fn write(&self, out: &Path) -> anyhow::Result<()> {
        let path = out.join("run.json");
        std::fs::write(&path, serde_json::to_string_pretty(&self.value)? + "\n")
            .with_context(|| format!("cannot write {}", path.display()))
    }
}
use crate::select;

/// Episode-seed streams of a run (see `policy::rollout::episode_seed`).
const DEMO_STREAM: u64 = 0;
const RL_STREAM: u64 = 1;

#[derive(Debug, clap::Args)]
pub struct TrainArgs {
    #[command(flatten)]
    pub run: RunOverrides,
    /// Test episodes of the final evaluation [default: 500]
    #[arg(long)]
    pub eval_episodes: Option<u32>,
    /// Checkpoint every N RL episodes [default: 1000]
    #[arg(long)]
    pub checkpoint_every: Option<u64>,
    /// Run directory [default: runs/<method>-<setting>-s<seed>]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Train in this one process instead of learner + actors + evaluator processes.
    #[arg(long)]
    pub single_process: bool,
    /// Actor processes (multi-process mode)
    #[arg(long, default_value_t = 2)]
    pub actors: u32,
    /// Data plane of the local run: iceoryx2 (shared memory) or zenoh
    #[arg(long, default_value = "iceoryx2")]
    pub transport: String,
    /// Skip the evaluator process (multi-process mode)
    #[arg(long)]
    pub no_evaluator: bool,
}

#[derive(Serialize)]
struct MetricsLine<'a> {
    phase: &'a str,
    episode: u64,
    epsilon: f64,
    outcome: &'a str,
    steps: u32,
    return_sum: f64,
    loss: f32,
    success_rate_window: f64,
    collision_rate_window: f64,
    timeout_rate_window: f64,
    policy_version: u64,
    env_steps: u64,
    replay_size: usize,
    wall_s: f64,
}

/// The largest `wall_s` in a metrics log (zero when there is none).
fn last_wall(path: &Path) -> Duration {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let wall_s = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v.get("wall_s").and_then(|w| w.as_f64()))
        .filter(|w| w.is_finite() && *w >= 0.0)
        .fold(0.0, f64::max);
    Duration::from_secs_f64(wall_s)
}

/// Cuts the `metrics.jsonl` of a run resumed from a checkpoint after `rl_episodes` RL episodes
/// back to that checkpoint, and returns how many lines it dropped: the RL episodes from
/// `rl_episodes` on and the validations the resumed run does again (those after the checkpoint;
/// from a checkpoint straight after imitation, the one at episode 0 too), which an interrupted run
/// logged after its last checkpoint, and a line torn by a crash (appended to, it would swallow the
/// next line). Lines of other phases stay. Written beside the log and renamed over it, so a crash
/// here leaves the old log or the new one.
fn trim_metrics(path: &Path, rl_episodes: u64) -> anyhow::Result<usize> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    };
    let keep = |line: &str| -> bool {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            return false;
        };
        let episode = v.get("episode").and_then(|e| e.as_u64());
        match v.get("phase").and_then(|p| p.as_str()) {
            Some("rl") => episode.is_some_and(|e| e < rl_episodes),
            Some("validation") => {
                episode.is_some_and(|e| e < rl_episodes || (e == rl_episodes && e > 0))
            }
            _ => v.is_object(),
        }
    };
    let mut kept = String::with_capacity(text.len());
    let mut dropped = 0;
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        if keep(line) {
            kept.push_str(line);
            kept.push('\n');
        } else {
            dropped += 1;
        }
    }
    if dropped > 0 {
        let tmp = path.with_extension("jsonl.tmp");
        let write = || -> std::io::Result<()> {
            let mut f = std::fs::File::create(&tmp)?;
            f.write_all(kept.as_bytes())?;
            f.sync_all()?;
            std::fs::rename(&tmp, path)
        };
        write().with_context(|| format!("cannot rewrite {}", path.display()))?;
    }
    Ok(dropped)
}

/// One point of the learning curve (`phase = "validation"` in `metrics.jsonl`): the evaluator's
/// validation of the online network, with the learner's counters and the run's clock.
fn validation_line(
    core: &LearnerCore,
    spec: &RunSpec,
    elapsed: Duration,
) -> anyhow::Result<serde_json::Value> {
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let c = core.counters();
    let point = evaluator::process::validate(spec, core.online(), threads, c.rl_episodes, elapsed)?;
    let mut line = serde_json::to_value(&point)?;
    line["env_steps"] = c.env_steps.into();
    line["policy_version"] = c.policy_version.into();
    Ok(line)
}

pub(crate) fn resolve(args: &TrainArgs) -> anyhow::Result<Resolved> {
    let mut file = args.run.load()?;
    let mut problems = Vec::new();
    if let Some(n) = args.eval_episodes {
        file.train.eval_episodes = n;
    }
    if let Some(n) = args.checkpoint_every {
        file.train.checkpoint_every_episodes = n;
    }
    if file.run.method == "orca" {
        problems.push("method orca is not trainable; evaluate it with `fsrl sim`".to_string());
    }
    Ok(file.resolve(problems)?)
}

fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr_with_hz(4));
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what:>10} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} ({{per_sec}}, ETA {{eta}}) {{msg}}"
        ))
        .expect("valid template"),
    );
    bar
}

/// Prints a plain progress line when stderr is not a terminal (CI logs), at most every 10 s.
struct PlainProgress {
    last: Instant,
}

impl PlainProgress {
    fn tick(&mut self, bar: &ProgressBar, force: bool) {
        if bar.is_hidden() && (force || self.last.elapsed() >= Duration::from_secs(10)) {
            self.last = Instant::now();
            let elapsed = bar.elapsed().as_secs_f64();
            let rate = bar.position() as f64 / elapsed.max(1e-9);
            let left =
                bar.length().unwrap_or(0).saturating_sub(bar.position()) as f64 / rate.max(1e-9);
            eprintln!(
                "{}/{} ({rate:.2}/s, ETA {left:.0} s) {}",
                bar.position(),
                bar.length().unwrap_or(0),
                bar.message()
            );
        }
    }
}

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    if !args.single_process {
        return crate::launch::run(args);
    }
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                eprintln!("second interrupt: exiting without a final checkpoint");
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: finishing the current episode and writing a checkpoint (Ctrl-C again to quit at once)");
        })
        .context("cannot install the Ctrl-C handler")?;
    }
    let resolved = resolve(&args)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| resolved.default_run_dir());
    let ckpt_dir = out.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)
        .with_context(|| format!("cannot create {}", ckpt_dir.display()))?;
    // One training per run directory, as the learner process holds it in multi-process mode.
    let _lock = learner::store::RunLock::acquire(&out)?;
    let latest = run_checkpoint(&out, args.resume)?;

    let (mut core, resolved) = if args.resume {
        let mut loaded = checkpoint::load(&latest)?;
        if let Some(n) = args.run.rl_episodes {
            loaded.core.set_rl_episodes(n);
        }
        let mut file = resolved.file.clone();
        file.run.method = loaded.core.method().name().to_string();
        file.run.setting = loaded.run.setting.clone();
        file.run.seed = loaded.run.run_seed;
        file.sim = loaded.sim.clone();
        file.train = loaded.core.config().clone();
        let c = loaded.core.counters();
        eprintln!(
            "resuming {} from {}: {} RL episodes done, policy version {}",
            out.display(),
            latest.display(),
            c.rl_episodes,
            c.policy_version
        );
        (loaded.core, file.resolve(Vec::new())?)
    } else {
        let core = LearnerCore::new(
            resolved.method,
            resolved.file.train.clone(),
            resolved.file.sim.humans.count,
            resolved.file.sim.dt_s,
            resolved.file.run.seed,
        )?;
        (core, resolved)
    };
    let file = &resolved.file;
    let method = resolved.method;
    let setting = resolved.setting;
    let run_seed = file.run.seed;
    let train = core.config().clone();
    let sim_cfg = method.sim_config(&file.sim);
    std::fs::write(out.join("config.toml"), toml::to_string(file)?)
        .with_context(|| format!("cannot write {}", out.join("config.toml").display()))?;
    let run_info = RunInfo {
        run_id: out
            .file_name()
            .map_or_else(|| "run".into(), |n| n.to_string_lossy().into_owned()),
        setting: setting.name().to_string(),
        run_seed,
        accepted_below: Default::default(),
    };
    let metrics_path = out.join("metrics.jsonl");
    // A resumed run's log is cut back to its checkpoint, and its clock goes on from there.
    let wall0 = if args.resume {
        let dropped = trim_metrics(&metrics_path, core.counters().rl_episodes)?;
        if dropped > 0 {
            eprintln!(
                "{}: dropped {dropped} lines logged after the checkpoint (the resumed run does that work again)",
                metrics_path.display()
            );
        }
        last_wall(&metrics_path)
    } else {
        Duration::ZERO
    };
    let mut metrics = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&metrics_path)
        .with_context(|| format!("cannot open {}", metrics_path.display()))?;
    let save = |core: &LearnerCore, path: &Path| -> anyhow::Result<()> {
        checkpoint::save(path, core, &sim_cfg, &run_info)?;
        Ok(())
    };
    let mut plain = PlainProgress {
        last: Instant::now(),
    };
    let mut env = Env::new(sim_cfg.clone(), setting, 0)?;
    let start = Instant::now();
    // Where the time goes (run.json; a resumed run adds to what the earlier ones recorded).
    let mut timing = RunTiming::read(&out, "single-process");
    eprintln!(
        "training {method} on {setting} (seed {run_seed}) in {}: {} demonstrations × {} epochs, {} RL episodes",
        out.display(),
        train.imitation.episodes,
        train.imitation.epochs,
        train.rl.episodes
    );

    // Imitation learning (skipped when the checkpoint already has it).
    if !core.counters().imitation_done {
        let bar = progress_bar(train.imitation.episodes, "demos");
        for k in 0..train.imitation.episodes {
            let ep = rollout(
                &mut env,
                episode_seed(run_seed, DEMO_STREAM, k),
                Behaviour::Orca {
                    safety_space_m: train.imitation.safety_space_m,
                },
            )?;
            core.add_episode(&ep, true)?;
            bar.inc(1);
            plain.tick(&bar, false);
            if stop.load(Ordering::SeqCst) {
                bail!("interrupted during demonstrations (nothing to checkpoint yet; rerun the same command)");
            }
        }
        bar.finish_and_clear();
        // The loss is only meaningful against the spread of its targets (an MSE near the
        // variance means the network predicts little more than the mean return).
        let returns = core.replay().columns().returns;
        let n = returns.len().max(1) as f64;
        let mean = returns.iter().map(|&r| r as f64).sum::<f64>() / n;
        let target_var = returns
            .iter()
            .map(|&r| (r as f64 - mean).powi(2))
            .sum::<f64>()
            / n;
        let bar = progress_bar(train.imitation.epochs as u64, "imitation");
        bar.set_message(format!("{} transitions", core.replay().len()));
        core.imitation(train.imitation.epochs, |epoch, loss| {
            bar.inc(1);
            bar.set_message(format!("loss {loss:.5}"));
            plain.tick(&bar, false);
            let line = serde_json::json!({"phase": "imitation", "epoch": epoch, "loss": loss, "target_mean": mean, "target_var": target_var, "wall_s": (wall0 + start.elapsed()).as_secs_f64()});
            let _ = writeln!(metrics, "{line}");
        })?;
        bar.finish_and_clear();
        core.start_rl()?;
        save(&core, &ckpt_dir.join("imitation.ckpt"))?;
        save(&core, &latest)?;
        eprintln!(
            "imitation done: loss {:.5}, {} transitions",
            core.imitation_loss()?,
            core.replay().len()
        );
        timing.add_s("warm_start_s", start.elapsed().as_secs_f64());
    }

    // Deep V-learning.
    let mut lookahead = Lookahead::new(train.gamma, train.human_model.into(), method.human_order())
        .with_terminal_previews(train.terminal_previews);
    let mut window: VecDeque<Outcome> = VecDeque::with_capacity(100);
    let first = core.counters().rl_episodes;
    let bar = progress_bar(train.rl.episodes, "rl");
    bar.set_position(first);
    bar.reset_eta();
    let rl_start = Instant::now();
    let mut interrupted = false;
    let validate_every = train.validation_every_episodes;
    let spec = RunSpec {
        method,
        setting,
        sim: file.sim.clone(),
        train: train.clone(),
        seed: run_seed,
    };
    let validation_time = std::cell::Cell::new(Duration::ZERO);
    let validate = |core: &LearnerCore, metrics: &mut std::fs::File| -> anyhow::Result<()> {
        let t0 = Instant::now();
        let line = validation_line(core, &spec, wall0 + start.elapsed())?;
        if train.select != Select::Last {
            // The snapshot before its line: a line always has its weights on disk.
            let path = select::snapshot_path(&out, core.counters().rl_episodes);
            let dir = select::snapshot_dir(&out);
            std::fs::create_dir_all(&dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            Model::from_core(core, &sim_cfg, &run_info)?.save(&path)?;
        }
        writeln!(metrics, "{}", serde_json::to_string(&line)?)?;
        validation_time.set(validation_time.get() + t0.elapsed());
        Ok(())
    };
    if validate_every > 0 && first == 0 {
        validate(&core, &mut metrics)?;
    }
    for k in first..train.rl.episodes {
        let epsilon = core.epsilon();
        let version = core.counters().policy_version;
        let ep = rollout(
            &mut env,
            episode_seed(run_seed, RL_STREAM, k),
            Behaviour::Net {
                net: core.online(),
                lookahead: &mut lookahead,
                epsilon,
                policy_version: version,
            },
        )?;
        core.add_episode(&ep, false)?;
        let loss = core.train_rl(train.rl.batches_per_episode)?;
        if window.len() == 100 {
            window.pop_front();
        }
        window.push_back(ep.outcome);
        let rate =
            |o: Outcome| window.iter().filter(|x| **x == o).count() as f64 / window.len() as f64;
        let c = core.counters();
        let done = (k + 1 - first) as f64;
        let eps_per_s = done / rl_start.elapsed().as_secs_f64().max(1e-9);
        let line = MetricsLine {
            phase: "rl",
            episode: k,
            epsilon,
            outcome: ep.outcome.name(),
            steps: ep.summary.steps,
            return_sum: ep.summary.return_sum,
            loss,
            success_rate_window: rate(Outcome::ReachGoal),
            collision_rate_window: rate(Outcome::Collision),
            timeout_rate_window: rate(Outcome::Timeout),
            policy_version: c.policy_version,
            env_steps: c.env_steps,
            replay_size: core.replay().len(),
            wall_s: (wall0 + start.elapsed()).as_secs_f64(),
        };
        writeln!(metrics, "{}", serde_json::to_string(&line)?)?;
        bar.inc(1);
        bar.set_message(format!(
            "ε {epsilon:.3} success {:.2} loss {loss:.5} {eps_per_s:.2} ep/s",
            line.success_rate_window
        ));
        plain.tick(&bar, false);
        if validate_every > 0 && ((k + 1) % validate_every == 0 || k + 1 == train.rl.episodes) {
            validate(&core, &mut metrics)?;
            bar.reset_eta();
        }
        let every = train.checkpoint_every_episodes;
        if every > 0 && (k + 1) % every == 0 {
            save(&core, &latest)?;
        }
        if stop.load(Ordering::SeqCst) {
            interrupted = true;
            break;
        }
    }
    plain.tick(&bar, true);
    bar.finish_and_clear();
    save(&core, &latest)?;
    metrics.flush()?;
    timing.add_s("validation_s", validation_time.get().as_secs_f64());
    timing.add_s(
        "rl_s",
        (rl_start.elapsed().saturating_sub(validation_time.get())).as_secs_f64(),
    );
    timing.add_s("total_s", start.elapsed().as_secs_f64());
    timing.write(&out)?;
    if interrupted {
        eprintln!(
            "checkpoint written to {} after {} RL episodes; continue with the same command and --resume",
            latest.display(),
            core.counters().rl_episodes
        );
        return Ok(());
    }

    // Final evaluation on the setting's test seeds: the run's policy by its selection rule.
    let final_start = Instant::now();
    final_evaluation(&out, &spec)?;
    timing.add_s("final_evaluation_s", final_start.elapsed().as_secs_f64());
    timing.add_s("total_s", final_start.elapsed().as_secs_f64());
    timing.write(&out)?;
    println!(
        "run directory: {} (config.toml, checkpoints/, metrics.jsonl, report.md, report.json); {:.1} s in all",
        out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(path: &Path) -> Vec<serde_json::Value> {
        std::fs::read_to_string(path)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect()
    }

    #[test]
    fn a_log_is_cut_back_to_a_checkpoint_taken_straight_after_imitation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        std::fs::write(
            &path,
            concat!(
                "{\"phase\":\"imitation\",\"epoch\":0,\"wall_s\":3.0}\n",
                "{\"phase\":\"imitation\",\"epoch\":1,\"wall_s\":7.0}\n",
                "{\"phase\":\"validation\",\"episode\":0,\"wall_s\":9.0}\n",
                "{\"phase\":\"rl\",\"episode\":0,\"wall_s\":10.0}\n",
                "{\"phase\":\"rl\",\"episode\":1,\"wall_s\":11.0}\n",
                "\n",
                "{\"phase\":\"rl\",\"epi",
            ),
        )
        .unwrap();
        // The checkpoint after imitation: the resumed run validates episode 0 again.
        assert_eq!(trim_metrics(&path, 0).unwrap(), 4);
        let kept = lines(&path);
        assert_eq!(kept.len(), 2);
        assert!(kept.iter().all(|v| v["phase"] == "imitation"));
        assert_eq!(last_wall(&path), Duration::from_secs(7));
        // Nothing more to cut: the file is left as it is.
        assert_eq!(trim_metrics(&path, 0).unwrap(), 0);
        // No log yet: nothing to do.
        assert_eq!(trim_metrics(&dir.path().join("none.jsonl"), 5).unwrap(), 0);
    }

    #[test]
    fn a_later_checkpoint_keeps_its_own_validation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.jsonl");
        let mut text = String::new();
        for k in 0..6 {
            text += &format!("{{\"phase\":\"rl\",\"episode\":{k}}}\n");
            if (k + 1) % 2 == 0 {
                text += &format!("{{\"phase\":\"validation\",\"episode\":{}}}\n", k + 1);
            }
        }
        std::fs::write(&path, text).unwrap();
        // Checkpoint after 4 episodes, written after the validation at 4.
        assert_eq!(trim_metrics(&path, 4).unwrap(), 3);
        let kept: Vec<(String, u64)> = lines(&path)
            .iter()
            .map(|v| {
                (
                    v["phase"].as_str().unwrap().to_string(),
                    v["episode"].as_u64().unwrap(),
                )
            })
            .collect();
        let expect = [
            ("rl", 0),
            ("rl", 1),
            ("validation", 2),
            ("rl", 2),
            ("rl", 3),
            ("validation", 4),
        ];
        assert_eq!(
            kept,
            expect.map(|(p, e)| (p.to_string(), e)).to_vec(),
            "episodes 4 and 5 and the validation at 6 go"
        );
    }
}
