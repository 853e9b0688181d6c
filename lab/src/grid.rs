//! The paper's grid of runs (methods × settings × seeds) as `fsrl reproduce` plans it: the
//! runs in their order, where each stands on disk (finished, to resume, to restart, new; a model
//! and an evaluation current or not), the shard of the grid a scheduler's task trains, and how
//! long the rest will take (rough costs, calibrated on the steps timed). Nothing here starts a
//! process: the binary runs what the plan says.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use policy::method::{Method, TrainConfig};
use sim::{Setting, SimConfig};

use crate::report::{EvalReport, EVAL_KIND};
use crate::run::{run_name, RunFile};

/// One run of the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cell {
    pub method: Method,
    pub setting: Setting,
    pub seed: u64,
}

/// The grid in the order it is run: seed-major, then setting, then method, each list in the
/// order given (so the first seed covers the whole grid before the second starts).
pub fn cells(methods: &[Method], settings: &[Setting], seeds: &[u64]) -> Vec<Cell> {
    let mut out = Vec::with_capacity(methods.len() * settings.len() * seeds.len());
    for &seed in seeds {
        for &setting in settings {
            for &method in methods {
                out.push(Cell {
                    method,
                    setting,
                    seed,
                });
            }
        }
    }
    out
}

/// Where everything goes.
pub struct Layout {
    pub runs: PathBuf,
    pub models: PathBuf,
}

impl Layout {
    pub fn run_dir(&self, name: &str) -> PathBuf {
        self.runs.join(name)
    }

    pub fn model(&self, name: &str) -> PathBuf {
        self.models.join(format!("{name}.fsrlm"))
    }

    pub fn eval_dir(&self, name: &str) -> PathBuf {
        self.runs.join("eval").join(name)
    }

    pub fn orca_eval_dir(&self) -> PathBuf {
        self.runs.join("eval").join("orca")
    }
}

// ---------------------------------------------------------------------------------------------
// What is done already.

/// Where a run's training stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Training {
    /// `report.json` exists.
    Finished,
    /// Interrupted: `checkpoints/latest.ckpt` without `report.json` (the first checkpoint is
    /// written after imitation, so only RL is left).
    Resume {
        /// RL episodes in `metrics.jsonl`: the checkpoint's, or more when the run stopped
        /// without one (the resumed training does those again and cuts them from the log).
        rl_done: u64,
    },
    /// A directory with neither (stopped during imitation): removed and started again.
    Restart,
    New,
}

impl Training {
    pub fn of(run_dir: &Path) -> Training {
        if run_dir.join("report.json").is_file() {
            Training::Finished
        } else if run_dir.join("checkpoints").join("latest.ckpt").is_file() {
            Training::Resume {
                rl_done: rl_done(&run_dir.join("metrics.jsonl")),
            }
        } else if run_dir.exists() {
            Training::Restart
        } else {
            Training::New
        }
    }

    /// How the plan table names this state.
    pub fn text(self) -> String {
        match self {
            Training::Finished => "finished".into(),
            Training::Resume { rl_done } => {
                format!("resume ({rl_done} RL ep. logged; from the last checkpoint)")
            }
            Training::Restart => "restart".into(),
            Training::New => "new".into(),
        }
    }
}

/// RL episodes logged in a metrics file (the last `phase = "rl"` line's episode + 1).
fn rl_done(metrics: &Path) -> u64 {
    let text = std::fs::read_to_string(metrics).unwrap_or_default();
    text.lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .find(|v| v["phase"] == "rl")
        .and_then(|v| v["episode"].as_u64())
        .map_or(0, |e| e + 1)
}

/// The modification time of a file (`None` for a directory or nothing).
fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path)
        .ok()
        .filter(|m| m.is_file())
        .and_then(|m| m.modified().ok())
}

/// A model file at least as new as its run's `report.json`.
pub fn model_is_current(model: &Path, run_dir: &Path) -> bool {
    match (modified(model), modified(&run_dir.join("report.json"))) {
        (Some(m), Some(r)) => m >= r,
        _ => false,
    }
}

/// An `eval.json` in `dir` of one policy on `settings` with `episodes` test episodes each, of
/// `source` (the model evaluated) when given: of its exact bytes where the report records their
/// SHA-256 (a checkout or a copy changes modification times, not contents), otherwise at least
/// as new as it.
pub fn eval_is_current(
    dir: &Path,
    settings: &[Setting],
    episodes: u32,
    source: Option<&Path>,
) -> bool {
    let path = dir.join("eval.json");
    let Some(written) = modified(&path) else {
        return false;
    };
    let Some(report) = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str::<EvalReport>(&t).ok())
    else {
        return false;
    };
    if let Some(source) = source {
        let recorded = report
            .subjects
            .first()
            .and_then(|s| s.checkpoint_sha256.as_ref());
        let same = match recorded {
            Some(sha) => crate::policy_file::file_sha256(source).is_ok_and(|c| &c == sha),
            None => modified(source).is_some_and(|s| written >= s),
        };
        if !same {
            return false;
        }
    }
    report.kind == EVAL_KIND
        && report.episodes_per_setting == episodes
        && report.subjects.len() == 1
        && settings
            .iter()
            .all(|&s| report.subjects[0].setting(s).is_some())
        // A report with a value no evaluation writes (edited, or corrupted) is done again.
        && report.subjects[0].settings.iter().all(|r| r.check().is_ok())
}

/// One run and what it still needs.
#[derive(Debug, Clone)]
pub struct Planned {
    pub cell: Cell,
    pub name: String,
    pub run_dir: PathBuf,
    pub model: PathBuf,
    pub eval_dir: PathBuf,
    pub training: Training,
    pub export: bool,
    pub eval: bool,
    /// Trained (or being trained) with another `[sim]` or `[train]` than the config file's.
    pub config_differs: bool,
}

impl Planned {
    /// The run of `cell` in `layout`, to be trained with `sim` and `train` (the `[train]` of
    /// the cell's run as `fsrl train` resolves it for its method and mode: `launch`'s rules;
    /// its config differs when the run on disk was trained with others).
    pub fn new(
        cell: Cell,
        layout: &Layout,
        sim: &SimConfig,
        train: &TrainConfig,
        episodes: u32,
    ) -> Planned {
        let name = run_name(cell.method, cell.setting, cell.seed);
        let run_dir = layout.run_dir(&name);
        let model = layout.model(&name);
        let eval_dir = layout.eval_dir(&name);
        let training = Training::of(&run_dir);
        let export = !model_is_current(&model, &run_dir);
        let eval = export || !eval_is_current(&eval_dir, &[cell.setting], episodes, Some(&model));
        let config_differs = matches!(training, Training::Finished | Training::Resume { .. })
            && RunFile::load(&run_dir.join("config.toml")).is_ok_and(|run| {
                run.train != *train
                    || cell.method.sim_config(&run.sim) != cell.method.sim_config(sim)
            });
        Planned {
            cell,
            name,
            run_dir,
            model,
            eval_dir,
            training,
            export,
            eval,
            config_differs,
        }
    }

    /// Nothing left to do.
    pub fn complete(&self) -> bool {
        self.training == Training::Finished && !self.export && !self.eval
    }
}

/// Every cell's run and what it still needs; `train_of` is the `[train]` a run of a method is
/// trained with ([`Planned::new`]).
pub fn plan(
    cells: &[Cell],
    layout: &Layout,
    sim: &SimConfig,
    train_of: &dyn Fn(Method) -> TrainConfig,
    episodes: u32,
) -> Vec<Planned> {
    cells
        .iter()
        .map(|&c| Planned::new(c, layout, sim, &train_of(c.method), episodes))
        .collect()
}

// ---------------------------------------------------------------------------------------------
// How long it takes.

/// Rough costs, used until steps of this invocation have been timed. Measured with `fsrl
/// train --single-process` on the 2-core development machine (2026-12): one SARL/FSRL RL
/// episode with 100 batches of 100 takes about 0.35 s, 92 % of it learning (BENCHMARKS.md); but
/// whole runs at 20 batches take longer than that share predicts (Experiment 10's 5000 × 20:
/// 13.5 min with imitation and validations, about 0.14 s an episode), so the estimate lets three
/// quarters scale with `rl.batches_per_episode`, fitted to both.
const RL_EPISODE_S: f64 = 0.35;
const RL_LEARNING_SHARE: f64 = 0.75;
/// One imitation epoch: a shuffled pass over replay, about 2.6 s once 1000 demonstrations are in
/// it (1000 × 30: 77 s; 3000 × 50: 136 s — replay holds at most `rl.replay_capacity`
/// transitions, so more demonstrations cost little more per epoch); fewer demonstrations
/// proportionally less.
const IMITATION_EPOCH_S: f64 = 2.6;
const IMITATION_FULL_EPISODES: f64 = 1000.0;
/// One test episode of a SARL network on both cores (~70 steps × 1.24 ms per decision / 2).
const TEST_EPISODE_S: f64 = 0.045;
/// LSTM-RL against SARL: 3.76 vs 9.59 ms per update, 0.60 vs 1.02 ms per decision
/// (BENCHMARKS.md).
const LSTM_RL_FACTOR: f64 = 0.45;

fn method_factor(m: Method) -> f64 {
    if m == Method::LstmRl {
        LSTM_RL_FACTOR
    } else {
        1.0
    }
}

/// Rough seconds to finish training from `state`: imitation, the RL episodes left with their
/// validations, the final evaluation.
pub fn rough_train_s(method: Method, t: &TrainConfig, state: Training) -> f64 {
    let (imitation, rl_from) = match state {
        Training::Finished => return 0.0,
        Training::Resume { rl_done } => (false, rl_done),
        Training::Restart | Training::New => (true, 0),
    };
    let il_s = if imitation {
        rough_imitation_s(t.imitation.episodes, t.imitation.epochs)
    } else {
        0.0
    };
    let left = t.rl.episodes.saturating_sub(rl_from) as f64;
    let episode_s = RL_EPISODE_S
        * ((1.0 - RL_LEARNING_SHARE) + RL_LEARNING_SHARE * t.rl.batches_per_episode as f64 / 100.0);
    let validations = if t.validation_every_episodes > 0 {
        (left / t.validation_every_episodes as f64).ceil()
    } else {
        0.0
    };
    let test_episodes = validations * t.validation_episodes as f64 + t.eval_episodes as f64;
    method_factor(method) * (il_s + left * episode_s + test_episodes * TEST_EPISODE_S)
}

/// Rough seconds of the imitation phase: `epochs` passes over `episodes` demonstrations.
fn rough_imitation_s(episodes: u64, epochs: u32) -> f64 {
    IMITATION_EPOCH_S * (episodes as f64 / IMITATION_FULL_EPISODES).min(1.0) * epochs as f64
}

/// Rough seconds of one evaluation.
pub fn rough_eval_s(method: Method, episodes: u32) -> f64 {
    method_factor(method) * episodes as f64 * TEST_EPISODE_S
}

/// Timed steps of this invocation against their rough estimates: the rough figure of a step
/// times measured/rough of the method's timed steps (for fresh runs of one config, the mean
/// measured time per run), else of all timed steps, else 1.
#[derive(Debug, Default)]
pub struct Calibration {
    train: Vec<(Method, f64, f64)>,
    eval: Vec<(Method, f64, f64)>,
}

impl Calibration {
    pub fn record_train(&mut self, m: Method, measured_s: f64, rough_s: f64) {
        self.train.push((m, measured_s, rough_s));
    }

    pub fn record_eval(&mut self, m: Method, measured_s: f64, rough_s: f64) {
        self.eval.push((m, measured_s, rough_s));
    }

    fn factor(samples: &[(Method, f64, f64)], m: Method) -> f64 {
        let ratio = |it: &mut dyn Iterator<Item = &(Method, f64, f64)>| {
            let (measured, rough) = it.fold((0.0, 0.0), |(a, b), x| (a + x.1, b + x.2));
            (rough > 0.0).then_some(measured / rough)
        };
        ratio(&mut samples.iter().filter(|x| x.0 == m))
            .or_else(|| ratio(&mut samples.iter()))
            .unwrap_or(1.0)
    }

    pub fn train_factor(&self, m: Method) -> f64 {
        Self::factor(&self.train, m)
    }

    pub fn eval_factor(&self, m: Method) -> f64 {
        Self::factor(&self.eval, m)
    }

    /// Seconds left for one planned run (0 when it will be skipped).
    pub fn estimate_s(&self, p: &Planned, t: &TrainConfig, episodes: u32, no_train: bool) -> f64 {
        let m = p.cell.method;
        if no_train && p.training != Training::Finished {
            return 0.0;
        }
        let train = rough_train_s(m, t, p.training) * self.train_factor(m);
        let eval = if p.eval {
            rough_eval_s(m, episodes) * self.eval_factor(m)
        } else {
            0.0
        };
        train + eval
    }

    /// Seconds left for `planned`.
    pub fn eta_s(
        &self,
        planned: &[Planned],
        t: &TrainConfig,
        episodes: u32,
        no_train: bool,
    ) -> f64 {
        planned
            .iter()
            .map(|p| self.estimate_s(p, t, episodes, no_train))
            .sum()
    }
}

/// `3h05m`, `12m40s`, `7s`.
pub fn duration_text(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s}s"),
        60..3600 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, (s % 3600) / 60),
    }
}

/// The plan as a table with a summary line.
pub fn describe(
    planned: &[Planned],
    orca_current: bool,
    t: &TrainConfig,
    episodes: u32,
    no_train: bool,
) -> String {
    let cal = Calibration::default();
    let w = planned
        .iter()
        .map(|p| p.name.len())
        .max()
        .unwrap_or(0)
        .max(20);
    let mut s = format!(
        "  {:<w$}  {:<28}  {:<7}  {:<9}  estimate\n",
        "run", "training", "model", "eval"
    );
    let (mut finished, mut resume, mut fresh, mut export, mut eval) = (0, 0, 0, 0, 0);
    let mut differs = false;
    for p in planned {
        let skip = no_train && p.training != Training::Finished;
        let mut training = p.training.text();
        if p.config_differs {
            training.push('*');
            differs = true;
        }
        if skip {
            training += ", skipped";
        }
        match p.training {
            Training::Finished => finished += 1,
            Training::Resume { .. } => resume += 1,
            Training::Restart | Training::New => fresh += 1,
        }
        export += usize::from(p.export && !skip);
        eval += usize::from(p.eval && !skip);
        let est = cal.estimate_s(p, t, episodes, no_train);
        let _ = writeln!(
            s,
            "  {:<w$}  {:<28}  {:<7}  {:<9}  {}",
            p.name,
            training,
            match (skip, p.export) {
                (true, _) => "–",
                (false, true) => "export",
                (false, false) => "ok",
            },
            match (skip, p.eval) {
                (true, _) => "–",
                (false, true) => "evaluate",
                (false, false) => "ok",
            },
            if est > 0.0 {
                duration_text(est)
            } else {
                "–".into()
            }
        );
    }
    let _ = writeln!(
        s,
        "  {:<w$}  {:<28}  {:<7}  {}",
        "orca (six settings)",
        "–",
        "–",
        if orca_current { "ok" } else { "evaluate" }
    );
    if differs {
        s += "  * trained with another [sim] or [train] than the config file; kept as it is (delete its directory to train it again)\n";
    }
    let _ = writeln!(
        s,
        "{} runs: {finished} finished, {resume} to resume, {fresh} to train{}; {export} to export, {eval} to evaluate; estimated {} (rough: {RL_EPISODE_S} s per SARL/FSRL RL episode at 100 batches, imitation {IMITATION_EPOCH_S} s an epoch over {IMITATION_FULL_EPISODES} or more demonstrations, LSTM-RL × {LSTM_RL_FACTOR}; calibrated on the runs timed once training starts)",
        planned.len(),
        if no_train && resume + fresh > 0 { " (skipped: --no-train)" } else { "" },
        duration_text(cal.eta_s(planned, t, episodes, no_train)),
    );
    s
}

// ---------------------------------------------------------------------------------------------
// Shards.

/// A share of the grid: runs whose index in the grid's order is `index` modulo `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    pub fn holds(&self, k: usize) -> bool {
        k % self.count as usize == self.index as usize
    }
}

fn parse_shard(text: &str) -> Result<Shard, String> {
    let (i, n) = text
        .split_once('/')
        .ok_or_else(|| format!("--shard {text}: expected I/N, e.g. 0/4"))?;
    let parse = |v: &str, what: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|_| format!("--shard {text}: {what} `{v}` is not a whole number"))
    };
    let (index, count) = (parse(i, "the index")?, parse(n, "the count")?);
    if count == 0 || index >= count {
        return Err(format!(
            "--shard {text}: the index must be in 0..{count} (0-based) and the count at least 1"
        ));
    }
    Ok(Shard { index, count })
}

/// The shard a scheduler's variables name, if any: Slurm's array (task id less the array's
/// first id, of the task count) or a Kubernetes Indexed Job (its completion index, of
/// `FSRL_SHARDS`, which the manifest sets).
fn scheduler_shard(
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Option<(Shard, &'static str)>, String> {
    let num = |k: &str| -> Result<Option<u32>, String> {
        env(k)
            .map(|v| {
                v.trim()
                    .parse::<u32>()
                    .map_err(|_| format!("{k}={v} is not a whole number"))
            })
            .transpose()
    };
    if let Some(id) = num("SLURM_ARRAY_TASK_ID")? {
        let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
        let count = num("SLURM_ARRAY_TASK_COUNT")?
            .ok_or("SLURM_ARRAY_TASK_ID is set but SLURM_ARRAY_TASK_COUNT is not")?;
        let index = id.checked_sub(min).ok_or(format!(
            "SLURM_ARRAY_TASK_ID {id} is below SLURM_ARRAY_TASK_MIN {min}"
        ))?;
        return parse_shard(&format!("{index}/{count}")).map(|s| Some((s, "Slurm")));
    }
    if let Some(index) = num("JOB_COMPLETION_INDEX")? {
        let count = num("FSRL_SHARDS")?
            .ok_or("JOB_COMPLETION_INDEX is set but FSRL_SHARDS (the Job's completions) is not")?;
        return parse_shard(&format!("{index}/{count}")).map(|s| Some((s, "Kubernetes")));
    }
    Ok(None)
}

/// The shard this invocation trains: `--shard`, else the scheduler's, else none (the whole
/// grid). `--shard` that disagrees with the scheduler's variables is an error.
pub fn shard_of(
    arg: Option<&str>,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Option<Shard>, String> {
    let given = arg.map(parse_shard).transpose()?;
    let sched = scheduler_shard(env)?;
    match (given, sched) {
        (Some(g), Some((s, who))) if g != s => Err(format!(
            "--shard {}/{} disagrees with the {who} variables ({}/{})",
            g.index, g.count, s.index, s.count
        )),
        (Some(g), _) => Ok(Some(g)),
        (None, s) => Ok(s.map(|(s, _)| s)),
    }
}

/// A run directory that another process trains now (its learner or trainer holds the lock on
/// `<run>/lock`), if any: two shards must never write the same run.
pub fn held_by_other(run_dir: &Path) -> Option<String> {
    if !run_dir.join("lock").exists() {
        return None;
    }
    learner::store::RunLock::acquire(run_dir)
        .err()
        .map(|e| format!("{}: {e}", run_dir.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn set(name: &str) -> Setting {
        name.parse().unwrap()
    }

    #[test]
    fn the_grid_is_seed_major_then_setting_then_method_in_the_order_given() {
        let (a, b) = (set("env2-visible"), set("env1-invisible"));
        let c = cells(&[Method::Fsrl, Method::Sarl], &[a, b], &[1, 0]);
        let got: Vec<(Method, Setting, u64)> =
            c.iter().map(|c| (c.method, c.setting, c.seed)).collect();
        assert_eq!(
            got,
            vec![
                (Method::Fsrl, a, 1),
                (Method::Sarl, a, 1),
                (Method::Fsrl, b, 1),
                (Method::Sarl, b, 1),
                (Method::Fsrl, a, 0),
                (Method::Sarl, a, 0),
                (Method::Fsrl, b, 0),
                (Method::Sarl, b, 0),
            ]
        );
    }

    #[test]
    fn run_directories_are_new_restarted_resumed_or_finished() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("run");
        assert_eq!(Training::of(&dir), Training::New);
        std::fs::create_dir_all(dir.join("checkpoints")).unwrap();
        std::fs::write(dir.join("config.toml"), "").unwrap();
        assert_eq!(Training::of(&dir), Training::Restart);
        std::fs::write(dir.join("checkpoints/latest.ckpt"), "x").unwrap();
        assert_eq!(Training::of(&dir), Training::Resume { rl_done: 0 });
        let lines: String = (0..5)
            .map(|k| format!("{{\"phase\":\"rl\",\"episode\":{k}}}\n"))
            .chain(["{\"phase\":\"validation\",\"episode\":5}\n".to_string()])
            .collect();
        std::fs::write(
            dir.join("metrics.jsonl"),
            format!("{{\"phase\":\"imitation\",\"epoch\":0}}\n{lines}"),
        )
        .unwrap();
        assert_eq!(Training::of(&dir), Training::Resume { rl_done: 5 });
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        assert_eq!(Training::of(&dir), Training::Finished);
    }

    fn touch(path: &Path, secs_ago: u64) {
        let f = std::fs::File::options().write(true).open(path).unwrap();
        f.set_modified(SystemTime::now() - Duration::from_secs(secs_ago))
            .unwrap();
    }

    fn eval_json(settings: &[&str], episodes: u32) -> String {
        let subject = crate::report::SubjectReport {
            label: "x".into(),
            method: "sarl".into(),
            checkpoint: None,
            checkpoint_sha256: None,
            policy_version: 1,
            run_seed: Some(0),
            planning_top_k: 0,
            planning_breadth: 0,
            shield_s: 0.0,
            progress_tolerance: 0.0,
            trained_setting: None,
            settings: settings
                .iter()
                .map(|s| {
                    let all_reached = sim::Aggregate {
                        episodes,
                        successes: episodes,
                        success_time_s: 12.0 * f64::from(episodes),
                        success_path_m: 10.0 * f64::from(episodes),
                        steps: 48 * u64::from(episodes),
                        ..sim::Aggregate::default()
                    };
                    crate::report::SettingReport::new(s, &all_reached)
                })
                .collect(),
        };
        serde_json::to_string(&EvalReport {
            kind: EVAL_KIND.into(),
            crowd: None,
            test_seed_start: 1000,
            episodes_per_setting: episodes,
            subjects: vec![subject],
        })
        .unwrap()
    }

    #[test]
    fn models_and_evaluations_are_redone_when_missing_stale_or_different() {
        let tmp = tempfile::tempdir().unwrap();
        let layout = Layout {
            runs: tmp.path().join("runs"),
            models: tmp.path().join("models"),
        };
        let name = "sarl-env2-visible-s0";
        let (run, model, eval) = (
            layout.run_dir(name),
            layout.model(name),
            layout.eval_dir(name),
        );
        std::fs::create_dir_all(&run).unwrap();
        std::fs::create_dir_all(&layout.models).unwrap();
        std::fs::create_dir_all(&eval).unwrap();
        std::fs::write(run.join("report.json"), "{}").unwrap();
        assert!(!model_is_current(&model, &run), "no model yet");
        std::fs::write(&model, "m").unwrap();
        touch(&run.join("report.json"), 100);
        touch(&model, 50);
        assert!(model_is_current(&model, &run));
        touch(&model, 200);
        assert!(!model_is_current(&model, &run), "older than the report");
        touch(&model, 50);

        let cell = Cell {
            method: Method::Sarl,
            setting: set("env2-visible"),
            seed: 0,
        };
        let file = RunFile::default();
        let p = Planned::new(cell, &layout, &file.sim, &file.train, 500);
        assert_eq!(p.training, Training::Finished);
        assert!(!p.export && p.eval && !p.complete());
        let json = eval.join("eval.json");
        std::fs::write(&json, eval_json(&["env2-visible"], 500)).unwrap();
        assert!(Planned::new(cell, &layout, &file.sim, &file.train, 500).complete());
        assert!(
            !Planned::new(cell, &layout, &file.sim, &file.train, 100).complete(),
            "another episode count"
        );
        std::fs::write(&json, eval_json(&["env1-visible"], 500)).unwrap();
        assert!(
            !Planned::new(cell, &layout, &file.sim, &file.train, 500).complete(),
            "another setting"
        );
        let mut hostile: serde_json::Value =
            serde_json::from_str(&eval_json(&["env2-visible"], 500)).unwrap();
        hostile["subjects"][0]["settings"][0]["disc"] = serde_json::json!(-1.0);
        std::fs::write(&json, hostile.to_string()).unwrap();
        assert!(
            !Planned::new(cell, &layout, &file.sim, &file.train, 500).complete(),
            "a Disc. of -1: evaluated again"
        );
        std::fs::write(&json, eval_json(&["env2-visible"], 500)).unwrap();
        touch(&json, 80);
        assert!(
            !Planned::new(cell, &layout, &file.sim, &file.train, 500).complete(),
            "older than the model"
        );
        touch(&model, 300);
        let p = Planned::new(cell, &layout, &file.sim, &file.train, 500);
        assert!(p.export && p.eval, "a model to export is evaluated again");
        // The ORCA evaluation covers all six settings.
        let orca = layout.orca_eval_dir();
        std::fs::create_dir_all(&orca).unwrap();
        std::fs::write(orca.join("eval.json"), eval_json(&["env2-visible"], 500)).unwrap();
        assert!(!eval_is_current(&orca, &Setting::ALL, 500, None));
        let all: Vec<&str> = Setting::ALL.iter().map(|s| s.name()).collect();
        std::fs::write(orca.join("eval.json"), eval_json(&all, 500)).unwrap();
        assert!(eval_is_current(&orca, &Setting::ALL, 500, None));
    }

    #[test]
    fn an_evaluation_that_records_the_model_hash_is_judged_by_content_not_time() {
        let tmp = tempfile::tempdir().unwrap();
        let (model, dir) = (tmp.path().join("m.fsrlm"), tmp.path().join("eval"));
        std::fs::create_dir_all(&dir).unwrap();
        // Like a model file: a payload followed by its CRC-32. The CRC-32 of such files is one
        // value for every payload of a length (what the reports recorded before SHA-256).
        let framed = |payload: &[u8]| {
            let mut bytes = payload.to_vec();
            bytes.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
            bytes
        };
        let (ours, theirs) = (framed(b"weights of seed 1"), framed(b"weights of seed 2"));
        assert_eq!(crc32fast::hash(&ours), crc32fast::hash(&theirs));
        let with = |field: &str, id: &str| {
            let mut v: serde_json::Value =
                serde_json::from_str(&eval_json(&["env2-visible"], 500)).unwrap();
            v["subjects"][0][field] = id.into();
            std::fs::write(dir.join("eval.json"), v.to_string()).unwrap();
        };
        let settings = [set("env2-visible")];
        std::fs::write(&model, b"weights").unwrap();
        assert_eq!(
            crate::policy_file::file_sha256(&model).unwrap(),
            "9a129038d9a00aed0cf6a7ea059ca50a813449061ab87848cf1a13eafdf33b2c",
            "sha256sum of b\"weights\""
        );
        std::fs::write(&model, &ours).unwrap();
        with(
            "checkpoint_sha256",
            &crate::policy_file::file_sha256(&model).unwrap(),
        );
        touch(&dir.join("eval.json"), 100);
        touch(&model, 10);
        assert!(
            eval_is_current(&dir, &settings, 500, Some(&model)),
            "a model newer than its report (a checkout) with the same bytes"
        );
        std::fs::write(&model, &theirs).unwrap();
        touch(&model, 200);
        assert!(
            !eval_is_current(&dir, &settings, 500, Some(&model)),
            "another run's weights of the same length, older than the report (a copy keeping its time)"
        );
        // A report of an older fsrl records only the CRC-32: it is not trusted as an id, and the
        // modification times decide.
        with(
            "checkpoint_crc32",
            &format!("{:08x}", crc32fast::hash(&theirs)),
        );
        touch(&dir.join("eval.json"), 100);
        touch(&model, 10);
        assert!(!eval_is_current(&dir, &settings, 500, Some(&model)));
        touch(&model, 300);
        assert!(eval_is_current(&dir, &settings, 500, Some(&model)));
        std::fs::remove_file(&model).unwrap();
        assert!(!eval_is_current(&dir, &settings, 500, Some(&model)));
    }

    #[test]
    fn a_run_trained_with_another_schedule_is_flagged() {
        let tmp = tempfile::tempdir().unwrap();
        let layout = Layout {
            runs: tmp.path().to_path_buf(),
            models: tmp.path().join("models"),
        };
        let cell = Cell {
            method: Method::Sarl,
            setting: set("env1-invisible"),
            seed: 0,
        };
        let dir = layout.run_dir(&run_name(cell.method, cell.setting, 0));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        let mut file = RunFile::default();
        // A resumed run writes its sim with the method's reward switches: not a difference.
        let mut written = file.clone();
        written.sim = cell.method.sim_config(&written.sim);
        std::fs::write(dir.join("config.toml"), toml::to_string(&written).unwrap()).unwrap();
        assert!(!Planned::new(cell, &layout, &file.sim, &file.train, 500).config_differs);
        file.train.rl.episodes = 7;
        assert!(Planned::new(cell, &layout, &file.sim, &file.train, 500).config_differs);
    }

    #[test]
    fn a_shard_comes_from_the_flag_or_the_scheduler_and_must_agree() {
        let none = |_: &str| None;
        assert_eq!(shard_of(None, &none), Ok(None));
        assert_eq!(
            shard_of(Some("1/4"), &none),
            Ok(Some(Shard { index: 1, count: 4 }))
        );
        for bad in ["4/4", "1/0", "x/2", "3", "-1/2"] {
            assert!(shard_of(Some(bad), &none).is_err(), "{bad}");
        }
        let slurm = |k: &str| match k {
            "SLURM_ARRAY_TASK_ID" => Some("7".to_string()),
            "SLURM_ARRAY_TASK_MIN" => Some("1".to_string()),
            "SLURM_ARRAY_TASK_COUNT" => Some("54".to_string()),
            _ => None,
        };
        assert_eq!(
            shard_of(None, &slurm),
            Ok(Some(Shard {
                index: 6,
                count: 54
            }))
        );
        assert_eq!(
            shard_of(Some("6/54"), &slurm),
            Ok(Some(Shard {
                index: 6,
                count: 54
            }))
        );
        let err = shard_of(Some("6/27"), &slurm).unwrap_err();
        assert!(err.contains("disagrees with the Slurm variables"), "{err}");
        let k8s = |k: &str| match k {
            "JOB_COMPLETION_INDEX" => Some("53".to_string()),
            "FSRL_SHARDS" => Some("54".to_string()),
            _ => None,
        };
        assert_eq!(
            shard_of(None, &k8s),
            Ok(Some(Shard {
                index: 53,
                count: 54
            }))
        );
        let k8s_bad = |k: &str| (k == "JOB_COMPLETION_INDEX").then(|| "54".to_string());
        assert!(shard_of(None, &k8s_bad)
            .unwrap_err()
            .contains("FSRL_SHARDS"));
        // Every run of a grid in exactly one shard.
        let n = 54;
        for count in [1u32, 2, 5, 54, 60] {
            let mut seen = vec![0; n];
            for index in 0..count {
                let sh = Shard { index, count };
                for (k, s) in seen.iter_mut().enumerate() {
                    if sh.holds(k) {
                        *s += 1;
                    }
                }
            }
            assert!(seen.iter().all(|&s| s == 1), "{count}");
        }
    }

    #[test]
    fn rough_estimates_follow_the_schedule() {
        // The paper's schedule (configs/paper.toml), validating every 500 episodes.
        let mut t = TrainConfig::default();
        t.imitation.episodes = 3000;
        t.imitation.epochs = 50;
        t.rl.episodes = 10_000;
        t.rl.epsilon_decay_episodes = 4000;
        t.rl.batches_per_episode = 100;
        t.validation_every_episodes = 500;
        // 3000 × 50 imitation (50 full epochs of 2.6 s) + 10,000 × 0.35 s + (20 validations ×
        // 100 + 500) test episodes.
        let fresh = 130.0 + 10_000.0 * 0.35 + 2500.0 * TEST_EPISODE_S;
        let sarl = rough_train_s(Method::Sarl, &t, Training::New);
        assert!((sarl - fresh).abs() < 1e-6, "{sarl}");
        assert_eq!(rough_train_s(Method::Fsrl, &t, Training::Restart), sarl);
        let lstm = rough_train_s(Method::LstmRl, &t, Training::New);
        assert!((lstm - LSTM_RL_FACTOR * fresh).abs() < 1e-6);
        // Resumed after 6000 episodes: no imitation, 4000 episodes and 8 validations left.
        let resumed = rough_train_s(Method::Sarl, &t, Training::Resume { rl_done: 6000 });
        let expected = 4000.0 * 0.35 + (800.0 + 500.0) * TEST_EPISODE_S;
        assert!((resumed - expected).abs() < 1e-6, "{resumed}");
        assert_eq!(rough_train_s(Method::Sarl, &t, Training::Finished), 0.0);
        // Half the batches: learning (75 %) halves; 500 demonstrations: half an epoch's cost.
        let mut half = t.clone();
        half.rl.batches_per_episode = 50;
        half.validation_every_episodes = 0;
        half.imitation.epochs = 25;
        half.imitation.episodes = 500;
        let h = rough_train_s(Method::Sarl, &half, Training::New);
        let expected = 32.5 + 10_000.0 * 0.35 * (0.25 + 0.375) + 500.0 * TEST_EPISODE_S;
        assert!((h - expected).abs() < 1e-6, "{h}");
        assert!((rough_eval_s(Method::Sarl, 500) - 500.0 * TEST_EPISODE_S).abs() < 1e-9);
    }

    #[test]
    fn the_eta_uses_the_methods_own_timings_then_all_timings() {
        let mut cal = Calibration::default();
        assert_eq!(cal.train_factor(Method::Fsrl), 1.0);
        cal.record_train(Method::Sarl, 200.0, 100.0);
        cal.record_train(Method::Sarl, 400.0, 100.0);
        assert_eq!(cal.train_factor(Method::Sarl), 3.0, "mean 300 s per run");
        assert_eq!(
            cal.train_factor(Method::Fsrl),
            3.0,
            "no FSRL run yet: all runs"
        );
        cal.record_train(Method::LstmRl, 50.0, 100.0);
        assert_eq!(cal.train_factor(Method::LstmRl), 0.5);
        assert_eq!(cal.train_factor(Method::Fsrl), 650.0 / 300.0);
        assert_eq!(cal.eval_factor(Method::Sarl), 1.0, "evaluations apart");

        // The grid's ETA: a fresh SARL run, a finished one left to evaluate, one finished
        // and evaluated.
        let t = TrainConfig::default();
        let cell = Cell {
            method: Method::Sarl,
            setting: set("env1-invisible"),
            seed: 0,
        };
        let planned = |training, eval| Planned {
            cell,
            name: String::new(),
            run_dir: PathBuf::new(),
            model: PathBuf::new(),
            eval_dir: PathBuf::new(),
            training,
            export: eval,
            eval,
            config_differs: false,
        };
        let grid = [
            planned(Training::New, true),
            planned(Training::Finished, true),
            planned(Training::Finished, false),
        ];
        let train_s = rough_train_s(Method::Sarl, &t, Training::New);
        let eval_s = rough_eval_s(Method::Sarl, 100);
        let eta = cal.eta_s(&grid, &t, 100, false);
        assert!((eta - (3.0 * train_s + 2.0 * eval_s)).abs() < 1e-6);
        let eta = cal.eta_s(&grid, &t, 100, true);
        assert!(
            (eta - eval_s).abs() < 1e-6,
            "--no-train skips the fresh run"
        );
        assert_eq!(cal.eta_s(&grid[2..], &t, 100, false), 0.0);
    }

    #[test]
    fn durations_read_well() {
        assert_eq!(duration_text(7.4), "7s");
        assert_eq!(duration_text(760.0), "12m40s");
        assert_eq!(duration_text(3.0 * 3600.0 + 5.0 * 60.0 + 10.0), "3h05m");
        assert_eq!(duration_text(-1.0), "0s");
    }
}
