//! The evaluator process: scores weight snapshots as they are broadcast (every N RL episodes and
//! the final one) on all six settings, publishes each report and writes it to disk.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use policy::method::RunSpec;
use policy::wire::net_from_weights;
use policy::{NetConfig, ValueNet};
use proto::{keys, EvalReport, Message, ProcessState, RunPhase};
use sim::Setting;
use transport::{AliveToken, Heartbeat, LatestSubscriber, Publisher, Transport, TransportError};

use crate::{evaluate, EvalError, SettingResult, Subject};

/// Evaluator settings.
#[derive(Debug, Clone)]
pub struct EvaluatorOptions {
    /// Evaluate a snapshot every this many RL episodes (0: only the final one).
    pub every_episodes: u64,
    pub episodes_per_setting: u32,
    pub seed_start: u64,
    pub settings: Vec<Setting>,
    pub threads: usize,
    /// Reports are written here: `eval-<version>.{json,md}` and, at the end, `report.{json,md}`;
    /// the learning curve (`validation.jsonl`) and the validated snapshots too
    /// (`checkpoints/validation/ep-<RL episodes>.fsrlm`, see [`KeepSnapshot`]).
    pub out_dir: PathBuf,
    /// Evaluate the final weights on `settings` when the run ends. The local launcher turns it
    /// off: it evaluates the run's chosen policy itself, as single-process training does.
    pub final_report: bool,
}

/// Keeps the weights a validation scored, before the validation's line is written (so a line
/// always has its weights on disk): `(net, weights version, RL episodes trained)`. The binary
/// writes a model file; the evaluator crate knows no file format of the learner's.
pub type KeepSnapshot<'a> = &'a dyn Fn(&policy::ValueNet, u64, u64) -> Result<(), String>;

/// The first multiple of `every` after `trained` (computed, not counted up to: a weights
/// message with a huge version costs no loop; saturates at `u64::MAX`).
pub fn due_after(trained: u64, every: u64) -> u64 {
    if every == 0 {
        return u64::MAX;
    }
    (trained / every).saturating_add(1).saturating_mul(every)
}

/// Where a resumed evaluator goes on: the first validation due after the last one in
/// `validation.jsonl` of `out_dir` (0 without one); a line that does not parse is skipped.
pub fn next_validation_due(out_dir: &std::path::Path, every: u64) -> u64 {
    let Ok(text) = std::fs::read_to_string(out_dir.join("validation.jsonl")) else {
        return 0;
    };
    let last = text
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter_map(|v| v.get("episode").and_then(|e| e.as_u64()))
        .max();
    match (last, every) {
        (None, _) | (_, 0) => 0,
        (Some(ep), every) => due_after(ep, every),
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error(transparent)]
    Eval(#[from] EvalError),
    #[error("{0}")]
    Other(String),
}

/// The wire report of `results`.
pub fn report(
    results: &[SettingResult],
    trained_episodes: u64,
    final_snapshot: bool,
) -> EvalReport {
    EvalReport {
        trained_episodes,
        final_snapshot,
        settings: results
            .iter()
            .map(|r| {
                let a = &r.aggregate;
                // Walls and people apart, and frozen robots, only where there are walls.
                let walled = |rate: f64| (!r.setting.is_paper()).then_some(rate);
                proto::SettingReport {
                    setting: r.setting.name().to_string(),
                    episodes: a.episodes,
                    success_rate: a.success_rate(),
                    collision_rate: a.collision_rate(),
                    timeout_rate: a.timeout_rate(),
                    nav_time_s: a.nav_time_s(),
                    discomfort: a.discomfort(),
                    mean_return: a.mean_return(),
                    path_length_m: a.path_length_m().unwrap_or(0.0),
                    smoothness_rad: a.mean_abs_rotation_rad(),
                    wall_collision_rate: walled(a.wall_collision_rate()),
                    people_collision_rate: walled(a.people_collision_rate()),
                    frozen_rate: walled(a.frozen_rate()),
                }
            })
            .collect(),
    }
}

/// The paper's table layout: Succ., Coll., Timeout, Nav. Time, Disc. per setting and averaged
/// over the paper's settings of each visibility; with a walled setting in the report, wall
/// collisions, people collisions and frozen robots in columns of their own ("–" elsewhere).
pub fn markdown(r: &EvalReport, method: &str, version: u64) -> String {
    let walled = r.settings.iter().any(|x| x.wall_collision_rate.is_some());
    let mut s = format!(
        "Method `{method}`, weights version {version}, {} RL episodes trained{}.\n\n| setting | episodes | Succ. | Coll. | Timeout | Nav. Time (s) | Disc. |{}\n|---|---|---|---|---|---|---|{}\n",
        r.trained_episodes,
        if r.final_snapshot { " (final)" } else { "" },
        if walled { " Wall coll. | People coll. | Frozen |" } else { "" },
        if walled { "---|---|---|" } else { "" },
    );
    let cell =
        |v: Option<f64>, digits: usize| v.map_or("–".to_string(), |x| format!("{x:.digits$}"));
    let row = |name: &str, n: u32, sr: f64, cr: f64, tr: f64, nav: Option<f64>, d: f64| {
        format!(
            "| {name} | {n} | {sr:.3} | {cr:.3} | {tr:.3} | {} | {d:.3} |",
            cell(nav, 2)
        )
    };
    let end = |x: Option<&proto::SettingReport>| {
        if !walled {
            return "\n".to_string();
        }
        let x = x.filter(|x| x.wall_collision_rate.is_some());
        format!(
            " {} | {} | {} |\n",
            cell(x.and_then(|x| x.wall_collision_rate), 3),
            cell(x.and_then(|x| x.people_collision_rate), 3),
            cell(x.and_then(|x| x.frozen_rate), 3)
        )
    };
    for x in &r.settings {
        s += &row(
            &x.setting,
            x.episodes,
            x.success_rate,
            x.collision_rate,
            x.timeout_rate,
            x.nav_time_s,
            x.discomfort,
        );
        s += &end(Some(x));
    }
    for vis in ["invisible", "visible"] {
        let rows: Vec<_> = r
            .settings
            .iter()
            .filter(|x| {
                x.setting
                    .parse::<Setting>()
                    .is_ok_and(|s| s.is_paper() && s.name().ends_with(&format!("-{vis}")))
            })
            .collect();
        if rows.len() > 1 {
            let n = rows.len() as f64;
            let navs: Vec<f64> = rows.iter().filter_map(|x| x.nav_time_s).collect();
            let nav = (!navs.is_empty()).then(|| navs.iter().sum::<f64>() / navs.len() as f64);
            s += &row(
                &format!("average {vis}"),
                rows.iter().map(|x| x.episodes).sum(),
                rows.iter().map(|x| x.success_rate).sum::<f64>() / n,
                rows.iter().map(|x| x.collision_rate).sum::<f64>() / n,
                rows.iter().map(|x| x.timeout_rate).sum::<f64>() / n,
                nav,
                rows.iter().map(|x| x.discomfort).sum::<f64>() / n,
            );
            s += &end(None);
        }
    }
    s
}

fn write(
    opts: &EvaluatorOptions,
    stem: &str,
    r: &EvalReport,
    method: &str,
    version: u64,
) -> Result<(), ProcessError> {
    let err = |e: std::io::Error| {
        ProcessError::Other(format!(
            "writing reports to {}: {e}",
            opts.out_dir.display()
        ))
    };
    std::fs::create_dir_all(&opts.out_dir).map_err(err)?;
    let json = serde_json::to_string_pretty(r).map_err(|e| ProcessError::Other(e.to_string()))?;
    replace_file(&opts.out_dir.join(format!("{stem}.json")), json.as_bytes()).map_err(err)?;
    replace_file(
        &opts.out_dir.join(format!("{stem}.md")),
        markdown(r, method, version).as_bytes(),
    )
    .map_err(err)?;
    Ok(())
}

/// Writes `path` whole or not at all: a synced temporary file in the same directory renamed
/// over it (a reader never sees half a report; a failed write leaves no temporary behind).
fn replace_file(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let dir = path.parent().unwrap_or(std::path::Path::new("."));
    let mut tmp = tempfile::NamedTempFile::new_in(dir)?;
    tmp.write_all(bytes)?;
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    std::fs::File::open(dir)?.sync_all()
}

/// One point of the learning curve (see [`validate`]).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ValidationPoint {
    pub phase: &'static str,
    /// RL episodes trained.
    pub episode: u64,
    pub episodes: u32,
    pub seed_start: u64,
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
    pub discomfort: f64,
    pub nav_time_s: Option<f64>,
    pub mean_return: f64,
    /// Seconds since the evaluator started.
    pub wall_s: f64,
    /// The weights version scored (the evaluator process knows it; the trainer adds its own).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub policy_version: Option<u64>,
}

impl ValidationPoint {
    /// The live metrics message of the point (names prefixed `validation_`).
    pub fn metrics(&self, trained: u64) -> proto::Metrics {
        let mut values = std::collections::BTreeMap::new();
        for (k, v) in [
            ("validation_episode", self.episode as f64),
            ("validation_episodes", self.episodes as f64),
            ("validation_success_rate", self.success_rate),
            ("validation_collision_rate", self.collision_rate),
            ("validation_timeout_rate", self.timeout_rate),
            ("validation_discomfort", self.discomfort),
            ("validation_mean_return", self.mean_return),
        ] {
            values.insert(k.to_string(), v);
        }
        if let Some(t) = self.nav_time_s {
            values.insert("validation_nav_time_s".to_string(), t);
        }
        proto::Metrics {
            env_steps: 0,
            episodes: trained,
            wall_time_s: self.wall_s,
            values,
        }
    }
}

/// Scores `net` greedily on the validation seeds of the run's own setting.
pub fn validate(
    spec: &RunSpec,
    net: &policy::ValueNet,
    threads: usize,
    trained: u64,
    elapsed: Duration,
) -> Result<ValidationPoint, ProcessError> {
    let results = evaluate(
        Subject::of_run(spec, net),
        &spec.sim,
        &[spec.setting],
        spec.train.validation_seed_start,
        spec.train.validation_episodes,
        threads,
    )?;
    let a = &results[0].aggregate;
    Ok(ValidationPoint {
        phase: "validation",
        episode: trained,
        episodes: a.episodes,
        seed_start: spec.train.validation_seed_start,
        success_rate: a.success_rate(),
        collision_rate: a.collision_rate(),
        timeout_rate: a.timeout_rate(),
        discomfort: a.discomfort(),
        nav_time_s: a.nav_time_s(),
        mean_return: a.mean_return(),
        wall_s: elapsed.as_secs_f64(),
        policy_version: None,
    })
}

fn append_validation(opts: &EvaluatorOptions, p: &ValidationPoint) -> Result<(), ProcessError> {
    use std::io::Write;
    let path = opts.out_dir.join("validation.jsonl");
    let err = |e: std::io::Error| ProcessError::Other(format!("writing {}: {e}", path.display()));
    std::fs::create_dir_all(&opts.out_dir).map_err(err)?;
    let line = serde_json::to_string(p).map_err(|e| ProcessError::Other(e.to_string()))?;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(err)?;
    writeln!(f, "{line}").map_err(err)
}

/// How the evaluator ended.
#[derive(Debug, Clone, PartialEq)]
pub enum EvaluatorExit {
    /// The run finished (with the final snapshot's report unless `final_report` is off).
    Finished(Option<EvalReport>),
    Stopped,
}

/// How long the evaluator waits, once the run is finished, for the final weights the learner
/// announced (it repeats them until the evaluator leaves) before it gives up with an error.
const FINAL_WEIGHTS_PATIENCE: Duration = Duration::from_secs(120);

/// Runs until the learner finishes the run (after validating and, with `final_report`,
/// evaluating its final weights: the version the `Finished` control names, or newer) or `stop`.
/// Its status heartbeats tell its state (starting until the first weights; running while it
/// scores weights; idle while none are due; stopping; failed with why) and its last warning.
pub fn run(
    transport: &Transport,
    spec: &RunSpec,
    opts: &EvaluatorOptions,
    stop: &AtomicBool,
    keep: Option<KeepSnapshot<'_>>,
) -> Result<EvaluatorExit, ProcessError> {
    let status = Heartbeat::new(transport)?;
    status.finish(run_inner(transport, spec, opts, stop, keep, &status))
}

fn run_inner(
    transport: &Transport,
    spec: &RunSpec,
    opts: &EvaluatorOptions,
    stop: &AtomicBool,
    keep: Option<KeepSnapshot<'_>>,
    status: &Heartbeat,
) -> Result<EvaluatorExit, ProcessError> {
    let net_cfg = spec.method.net().ok_or_else(|| {
        ProcessError::Other(format!("method {} has no weights to evaluate", spec.method))
    })?;
    let mut evaluator = Evaluator {
        spec,
        opts,
        keep,
        status,
        net_cfg,
        il_epochs: spec.train.imitation.epochs as u64,
        links: Links::open(transport)?,
        schedule: Schedule::new(spec, opts),
        tally: Tally::new(),
        finished_seen: None,
    };
    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(EvaluatorExit::Stopped);
        }
        if let Some(exit) = evaluator.step()? {
            return Ok(exit);
        }
    }
}

/// Waiting for weights between two looks at them.
const WEIGHTS_POLL: Duration = Duration::from_millis(200);

/// The evaluator's end of the run's topics, declared in this order: weights and control in,
/// reports out, its liveliness token, its metrics out.
struct Links {
    weights: LatestSubscriber<proto::Weights>,
    control: LatestSubscriber<proto::Control>,
    reports: Publisher<EvalReport>,
    _alive: AliveToken,
    metrics: Publisher<proto::Metrics>,
}

impl Links {
    fn open(transport: &Transport) -> Result<Self, ProcessError> {
        let run = transport.run().clone();
        let weights = transport.latest_subscriber(&keys::weights(&run))?;
        let control = transport.latest_subscriber(&keys::control(&run))?;
        let reports = transport.publisher(&keys::eval_report(&run, transport.sender().index))?;
        let alive = transport.declare_alive()?;
        let metrics = transport.publisher(&keys::metrics(&run, transport.sender()))?;
        Ok(Self {
            weights,
            control,
            reports,
            _alive: alive,
            metrics,
        })
    }

    /// Waits (at most [`WEIGHTS_POLL`]) for newer weights.
    fn wait(&self) -> Result<(), ProcessError> {
        let _ = self.weights.next(WEIGHTS_POLL)?;
        Ok(())
    }
}

/// Which weights are due: a report every `opts.every_episodes` RL episodes and a validation
/// point every `validation_every_episodes`; a report at most once per version, a validation
/// at most once per version and RL episode count.
struct Schedule {
    every: u64,
    next_due: u64,
    evaluated: Option<u64>,
    val_every: u64,
    next_val_due: u64,
    /// The last validated weights: version and RL episodes (the run's final weights may repeat
    /// an earlier version with more episodes, see [`Evaluator::newest_weights`]).
    validated: Option<(u64, u64)>,
    /// The last version looked at: when the weights go back (a learner restarted from an older
    /// checkpoint, or a rogue high version that was followed), the due points go back with
    /// them, so no version, however high, silences evaluation or validation until the learner
    /// passes it.
    last_version: Option<u64>,
}

impl Schedule {
    fn new(spec: &RunSpec, opts: &EvaluatorOptions) -> Self {
        // The learning curve: the run's own setting on the validation seeds (never the test
        // seeds).
        let val_every = spec.train.validation_every_episodes;
        // A restarted evaluator goes on from the next validation due (none is done twice).
        let next_val_due = next_validation_due(&opts.out_dir, val_every);
        if next_val_due > 0 {
            tracing::info!(next_val_due, "validations already done; going on");
        }
        Self {
            every: opts.every_episodes,
            next_due: opts.every_episodes,
            evaluated: None,
            val_every,
            next_val_due,
            validated: None,
            last_version: None,
        }
    }

    /// Looks at weights `version`, trained for `trained` RL episodes: brings the due points
    /// back if the version went back.
    fn follow(&mut self, version: u64, trained: u64) {
        if self.last_version.is_some_and(|last| version < last) {
            let back = trained.saturating_sub(1);
            tracing::warn!(
                version,
                last = self.last_version,
                "the weights went back to an older version; following them"
            );
            if self.every > 0 {
                self.next_due = self.next_due.min(due_after(back, self.every));
            }
            if self.val_every > 0 {
                self.next_val_due = self.next_val_due.min(due_after(back, self.val_every));
            }
        }
        self.last_version = Some(version);
    }

    fn report_due(&self, version: u64, trained: u64) -> bool {
        self.every > 0 && trained >= self.next_due && self.evaluated != Some(version)
    }

    /// Imitation bumps the version once per epoch: a validation point needs RL weights
    /// (`version >= il_epochs`). The run's end always takes one.
    fn validation_due(
        &self,
        spec: &RunSpec,
        il_epochs: u64,
        version: u64,
        trained: u64,
        finished: bool,
    ) -> bool {
        self.val_every > 0
            && spec.train.validation_episodes > 0
            && version >= il_epochs
            && self.validated != Some((version, trained))
            && (trained >= self.next_val_due || finished)
    }

    fn validated(&mut self, version: u64, trained: u64) {
        self.validated = Some((version, trained));
        self.next_val_due = due_after(trained, self.val_every);
    }

    fn reported(&mut self, version: u64, trained: u64) {
        self.evaluated = Some(version);
        if self.every > 0 {
            self.next_due = due_after(trained, self.every);
        }
    }
}

/// What the evaluator counts: where the time goes (scoring against waiting for weights), the
/// validations done, and weights that do not fit this run's network (counted, skipped; never
/// fatal until the end).
struct Tally {
    started: Instant,
    busy: Duration,
    validations: u64,
    bad_weights: u64,
    unusable: Option<u64>,
}

impl Tally {
    fn new() -> Self {
        Self {
            started: Instant::now(),
            busy: Duration::ZERO,
            validations: 0,
            bad_weights: 0,
            unusable: None,
        }
    }
}

/// Weights that arrived and may be scored: `finished` once they are the run's last.
struct Arrived {
    weights: Arc<Message<proto::Weights>>,
    finished: bool,
}

/// One evaluator at work: the run it follows, its links, its schedule and its tally.
struct Evaluator<'a> {
    spec: &'a RunSpec,
    opts: &'a EvaluatorOptions,
    keep: Option<KeepSnapshot<'a>>,
    status: &'a Heartbeat,
    net_cfg: NetConfig,
    il_epochs: u64,
    links: Links,
    schedule: Schedule,
    tally: Tally,
    /// When the learner was first seen finished with newer weights than those here.
    finished_seen: Option<Instant>,
}

impl Evaluator<'_> {
    /// One look at the newest weights: scores them if they are due (a validation point, a
    /// report, the final report), waits otherwise. `Some` when the evaluator is done.
    fn step(&mut self) -> Result<Option<EvaluatorExit>, ProcessError> {
        self.status.progress(0, self.tally.validations);
        self.status.beat();
        let Some(Arrived { weights, finished }) = self.newest_weights()? else {
            return Ok(None);
        };
        let version = weights.body.version;
        // The RL episodes the weights were trained on, as the learner says; a learner that does
        // not say advanced its version once per imitation epoch and once per RL episode.
        let trained = weights
            .body
            .rl_episodes
            .unwrap_or_else(|| version.saturating_sub(self.il_epochs));
        self.schedule.follow(version, trained);
        let report_due = self.schedule.report_due(version, trained);
        let validation_due =
            self.schedule
                .validation_due(self.spec, self.il_epochs, version, trained, finished);
        if !(validation_due || report_due || finished) {
            self.status.set_state(ProcessState::Idle);
            self.links.wait()?;
            return Ok(None);
        }
        if self.tally.unusable == Some(version) {
            if finished {
                return Err(ProcessError::Other(format!(
                    "the run's final weights (version {version}) are unusable; see the warnings"
                )));
            }
            self.links.wait()?;
            return Ok(None);
        }
        // Decoded once per version that is due, for the validation point and the report.
        let Some(net) = self.decode(&weights.body) else {
            return Ok(None);
        };
        self.status.set_state(ProcessState::Running);
        if validation_due {
            self.validation_point(&net, version, trained)?;
        }
        if finished && !self.opts.final_report {
            return Ok(Some(EvaluatorExit::Finished(None)));
        }
        if !(finished || report_due) {
            self.links.wait()?;
            return Ok(None);
        }
        let r = self.score_and_report(&net, version, trained, finished)?;
        if finished {
            write(self.opts, "report", &r, self.spec.method.name(), version)?;
            return Ok(Some(EvaluatorExit::Finished(Some(r))));
        }
        Ok(None)
    }

    /// The newest weights, or `None` after waiting for some. The learner sends its final
    /// weights before `Finished`, whose header names their version and whose body their RL
    /// episodes (`Control::final_rl_episodes`): until weights at least that new are here, the
    /// run's last weights are not (an error after [`FINAL_WEIGHTS_PATIENCE`]). The two topics
    /// keep no order between them, and the final weights may repeat the version of the last
    /// round's weights with more episodes: both are checked.
    fn newest_weights(&mut self) -> Result<Option<Arrived>, ProcessError> {
        let final_weights = self
            .links
            .control
            .latest()?
            .filter(|c| c.body.phase == RunPhase::Finished)
            .map(|c| (c.header.policy_version, c.body.final_rl_episodes));
        let Some(weights) = self.links.weights.latest()? else {
            self.links.wait()?;
            return Ok(None);
        };
        let version = weights.body.version;
        let trained = weights.body.rl_episodes;
        let finished = match final_weights {
            // Earlier weights than the final ones: an older version, or the final version with
            // fewer RL episodes (the last episodes were taken after the last round of updates).
            Some((last, episodes))
                if version < last
                    || (version == last
                        && matches!((trained, episodes), (Some(e), Some(n)) if e < n)) =>
            {
                let since = *self.finished_seen.get_or_insert_with(Instant::now);
                if since.elapsed() > FINAL_WEIGHTS_PATIENCE {
                    return Err(ProcessError::Other(format!(
                        "the run finished with weights version {last} ({} RL episodes), but the newest that arrived in {} s is version {version} ({} RL episodes)",
                        episodes.map_or("?".into(), |n| n.to_string()),
                        FINAL_WEIGHTS_PATIENCE.as_secs(),
                        trained.map_or("?".into(), |n| n.to_string())
                    )));
                }
                self.links.wait()?;
                return Ok(None);
            }
            Some(_) => true,
            None => false,
        };
        Ok(Some(Arrived { weights, finished }))
    }

    /// The network of `weights`, or `None` when they do not fit this run's: skipped and counted
    /// (a later version may be fine; an actor does the same).
    fn decode(&mut self, weights: &proto::Weights) -> Option<ValueNet> {
        let version = weights.version;
        match net_from_weights(weights, &self.net_cfg) {
            Ok(net) => Some(net),
            Err(e) => {
                let t = &mut self.tally;
                t.bad_weights += 1;
                t.unusable = Some(version);
                self.status
                    .error(format_args!("skipping weights version {version}: {e}"));
                if t.bad_weights.is_power_of_two() {
                    tracing::warn!(
                        version,
                        bad_weights = t.bad_weights,
                        "skipping weights it cannot use: {e}"
                    );
                }
                let mut m = proto::Metrics::default();
                m.values.insert("bad_weights".into(), t.bad_weights as f64);
                let _ = self.links.metrics.publish(version, &m);
                None
            }
        }
    }

    /// A point of the learning curve: the snapshot kept, then its line in `validation.jsonl`,
    /// then its live metrics.
    fn validation_point(
        &mut self,
        net: &ValueNet,
        version: u64,
        trained: u64,
    ) -> Result<(), ProcessError> {
        let t = &mut self.tally;
        let t0 = Instant::now();
        let mut point = validate(
            self.spec,
            net,
            self.opts.threads,
            trained,
            t.started.elapsed(),
        )?;
        point.policy_version = Some(version);
        if let Some(keep) = self.keep {
            // The snapshot before its line.
            keep(net, version, trained).map_err(ProcessError::Other)?;
        }
        append_validation(self.opts, &point)?;
        t.busy += t0.elapsed();
        t.validations += 1;
        let mut m = point.metrics(trained);
        let wall = t.started.elapsed().as_secs_f64();
        m.values.insert("validations".into(), t.validations as f64);
        m.values.insert("busy_s".into(), t.busy.as_secs_f64());
        m.values
            .insert("wait_s".into(), (wall - t.busy.as_secs_f64()).max(0.0));
        self.links.metrics.publish(version, &m)?;
        self.schedule.validated(version, trained);
        Ok(())
    }

    /// Scores the snapshot on the evaluation settings, publishes the report and writes it
    /// (`eval-<version>.{json,md}`).
    fn score_and_report(
        &mut self,
        net: &ValueNet,
        version: u64,
        trained: u64,
        finished: bool,
    ) -> Result<EvalReport, ProcessError> {
        tracing::info!(
            version,
            trained,
            final_snapshot = finished,
            "evaluating a snapshot"
        );
        let opts = self.opts;
        let results = evaluate(
            Subject::of_run(self.spec, net),
            &self.spec.sim,
            &opts.settings,
            opts.seed_start,
            opts.episodes_per_setting,
            opts.threads,
        )?;
        let r = report(&results, trained, finished);
        self.links.reports.publish(version, &r)?;
        write(
            opts,
            &format!("eval-{version:06}"),
            &r,
            self.spec.method.name(),
            version,
        )?;
        self.schedule.reported(version, trained);
        Ok(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_restarted_evaluator_goes_on_from_the_next_due_validation() {
        let dir = tempfile::tempdir().unwrap();
        // Nothing validated yet: the first one is due at once.
        assert_eq!(next_validation_due(dir.path(), 250), 0);
        std::fs::write(
            dir.path().join("validation.jsonl"),
            "{\"phase\":\"validation\",\"episode\":0}\n{\"phase\":\"validation\",\"episode\":253}\n{\"phase\":\"valid",
        )
        .unwrap();
        // The last one was at 253 (late, the learner went on): the next is due at 500; the
        // torn last line is skipped.
        assert_eq!(next_validation_due(dir.path(), 250), 500);
        std::fs::write(
            dir.path().join("validation.jsonl"),
            "{\"phase\":\"validation\",\"episode\":500}\n",
        )
        .unwrap();
        assert_eq!(next_validation_due(dir.path(), 250), 750);
        // No validations configured: nothing is due.
        assert_eq!(next_validation_due(dir.path(), 0), 0);
    }

    #[test]
    fn the_next_due_point_is_computed_even_for_a_huge_version() {
        assert_eq!(due_after(0, 250), 250);
        assert_eq!(due_after(249, 250), 250);
        assert_eq!(due_after(250, 250), 500);
        // A rogue version near u64::MAX: no loop, no overflow.
        assert_eq!(due_after(u64::MAX - 3, 250), u64::MAX);
        assert_eq!(due_after(7, 0), u64::MAX);
    }
}
