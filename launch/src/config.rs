//! The run configuration file (TOML): one typed struct, unknown keys rejected, every value
//! defaulted, validated once at start-up with every problem reported together.

use std::path::Path;

use anyhow::Context;
pub use lab::run::{run_name, RunSection};
use policy::method::{Method, ReplayRatio, Select, TrainConfig};
use serde::{Deserialize, Serialize};
use sim::{ConfigError, Setting, SimConfig};

/// The checkpoint of the run in `dir`, refusing to overwrite a run without `resume` and to
/// resume one that does not exist.
pub fn run_checkpoint(dir: &Path, resume: bool) -> anyhow::Result<std::path::PathBuf> {
    let ckpt = dir.join("checkpoints").join("latest.ckpt");
    if ckpt.exists() && !resume {
        anyhow::bail!(
            "{} already holds a run (checkpoint {}); pass --resume to continue it or --out to start another",
            dir.display(),
            ckpt.display()
        );
    }
    if resume && !ckpt.exists() {
        anyhow::bail!("--resume: no checkpoint at {}", ckpt.display());
    }
    Ok(ckpt)
}

/// The whole file. Each table belongs to one part of the system.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FileConfig {
    /// Whether the file said `[train] select` itself (its choice comes before the method's and
    /// the mode's: [`select_rule`]). Not a key of the file.
    #[serde(skip)]
    pub train_select_given: bool,
    pub run: RunSection,
    /// The simulator (SPEC §2–3).
    pub sim: SimConfig,
    /// The training schedule (SPEC §5).
    pub train: TrainConfig,
    /// How processes talk (zenoh session, iceoryx2 data plane).
    pub transport: TransportSection,
    pub learner: LearnerSection,
    pub actor: ActorSection,
    pub evaluator: EvaluatorSection,
}

/// The transport of every process of the run (`transport::TransportConfig` without the run id
/// and sender, which come from `[run]` and the role).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TransportSection {
    /// "zenoh" (any machines) or "iceoryx2" (shared memory, one machine; telemetry stays on zenoh).
    pub data_plane: transport::DataPlane,
    pub zenoh: transport::ZenohConfig,
    pub iceoryx2: transport::IceoryxConfig,
    pub max_message_bytes: usize,
    pub publish_timeout_ms: u64,
    pub subscriber_queue: usize,
}

impl Default for TransportSection {
    fn default() -> Self {
        let t = transport::TransportConfig::new(
            proto::RunId::new("local").expect("valid id"),
            proto::SenderId::new(proto::Role::Monitor, 0),
        );
        Self {
            data_plane: t.data_plane,
            zenoh: t.zenoh,
            iceoryx2: t.iceoryx2,
            max_message_bytes: t.max_message_bytes,
            publish_timeout_ms: t.publish_timeout_ms,
            subscriber_queue: t.subscriber_queue,
        }
    }
}

impl TransportSection {
    /// The transport config of `sender` in run `run_id`.
    pub fn for_sender(
        &self,
        run_id: &str,
        sender: proto::SenderId,
    ) -> anyhow::Result<transport::TransportConfig> {
        let run =
            proto::RunId::new(run_id).map_err(|e| anyhow::anyhow!("run.id `{run_id}`: {e}"))?;
        let mut t = transport::TransportConfig::new(run, sender);
        t.data_plane = self.data_plane;
        t.zenoh = self.zenoh.clone();
        t.iceoryx2 = self.iceoryx2.clone();
        t.max_message_bytes = self.max_message_bytes;
        t.publish_timeout_ms = self.publish_timeout_ms;
        t.subscriber_queue = self.subscriber_queue;
        Ok(t)
    }
}

/// The learner process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearnerSection {
    /// Checkpoints and the write-ahead log (default: `runs/<run.id>`).
    pub run_dir: Option<std::path::PathBuf>,
    /// Episodes an actor may run ahead of what the learner has accepted.
    pub in_flight_per_actor: u64,
    pub metrics_interval_ms: u64,
    /// After the run, how long to wait for actors and evaluators to leave.
    pub linger_ms: u64,
    /// Threads of the learner's updates (each batch is sharded over them; a run is bit-for-bit
    /// reproducible for a given count). 0: every core of the host.
    pub threads: usize,
}

impl Default for LearnerSection {
    fn default() -> Self {
        Self {
            run_dir: None,
            in_flight_per_actor: 2,
            metrics_interval_ms: 1000,
            linger_ms: 10_000,
            threads: 0,
        }
    }
}

/// An actor process.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ActorSection {
    /// Actor index (unique within the run).
    pub id: u32,
}

/// The evaluator process.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvaluatorSection {
    /// Evaluate a snapshot every this many RL episodes (0: only the final weights).
    pub every_episodes: u64,
    pub episodes_per_setting: u32,
    pub seed_start: u64,
    /// Settings to evaluate (default: all six).
    pub settings: Vec<String>,
    /// Worker threads.
    pub threads: usize,
    /// Where reports, the learning curve (`validation.jsonl`) and the validated snapshots
    /// (`checkpoints/validation/`) go (default: `<run_dir>/eval`).
    pub out_dir: Option<std::path::PathBuf>,
    /// Evaluate the final weights on `settings` when the run ends (the local launcher turns it
    /// off and evaluates the run's chosen policy on its own setting, as `--single-process`).
    pub final_report: bool,
}

impl Default for EvaluatorSection {
    fn default() -> Self {
        Self {
            every_episodes: 1000,
            episodes_per_setting: 500,
            seed_start: 1000,
            settings: Setting::ALL.iter().map(|s| s.name().to_string()).collect(),
            threads: 1,
            out_dir: None,
            final_report: true,
        }
    }
}

/// A validated run configuration.
#[derive(Debug, Clone)]
pub struct Resolved {
    pub method: Method,
    pub setting: Setting,
    pub file: FileConfig,
}

impl Resolved {
    pub fn spec(&self) -> policy::method::RunSpec {
        policy::method::RunSpec {
            method: self.method,
            setting: self.setting,
            sim: self.file.sim.clone(),
            train: self.file.train.clone(),
            seed: self.file.run.seed,
        }
    }

    /// `runs/<method>-<setting>-s<seed>`: where `fsrl train` puts a run by default.
    pub fn default_run_dir(&self) -> std::path::PathBuf {
        std::path::PathBuf::from("runs").join(run_name(
            self.method,
            self.setting,
            self.file.run.seed,
        ))
    }

    /// The run directory of the learner (and default home of everything else).
    pub fn run_dir(&self) -> std::path::PathBuf {
        self.file
            .learner
            .run_dir
            .clone()
            .unwrap_or_else(|| std::path::PathBuf::from("runs").join(&self.file.run.id))
    }

    /// A distributed run's `[train]`, by the rules: its replay ratio ([`replay_ratio`]) and its
    /// snapshot rule ([`select_rule`]), a resumed run's own from its `config.toml` (in `out`);
    /// checked before anything is written or started (a bad ratio would otherwise start every
    /// process and be refused by the learner). Without its evaluator (`evaluator` false) a run
    /// validates nothing and keeps no snapshot: its policy is its last weights (said on stderr,
    /// and recorded in the run's `config.toml`).
    pub fn for_processes(
        &mut self,
        out: &Path,
        resume: bool,
        flag: Option<Option<ReplayRatio>>,
        evaluator: bool,
    ) -> anyhow::Result<()> {
        let started = started_config(out, resume)?;
        let choice = self.file.select_choice();
        let train = &mut self.file.train;
        let own = started.as_ref().map(|f| f.train.rl.replay_ratio);
        let (ratio, from) = replay_ratio(Mode::Distributed, flag, own, train.rl.replay_ratio)
            .map_err(|_| anyhow::anyhow!("a distributed run takes any replay ratio"))?;
        let whence = match from {
            RatioSource::Flag => "--replay-ratio".to_string(),
            RatioSource::Started => format!(
                "{} (the run's own config; --replay-ratio overrides it)",
                out.join("config.toml").display()
            ),
            RatioSource::File | RatioSource::Default => "the run's config".to_string(),
        };
        train.rl.replay_ratio = ratio;
        let resumed = started.as_ref().map(|f| f.train.select);
        train.select = select_rule(self.method, train, choice, Mode::Distributed, resumed);
        if let Some(f) = &started {
            // A resumed run re-validates as it was started to (its `[train.revalidation]`).
            train.revalidation = f.train.revalidation;
        }
        check_train(train, &whence)?;
        if !evaluator && train.select != Select::Last {
            // Without the evaluator nothing is validated and no snapshot is kept.
            eprintln!(
                "note: --no-evaluator: no validations, so the run's policy is its last weights (train.select = \"last\" instead of \"{}\")",
                train.select.name()
            );
            train.select = Select::Last;
        }
        Ok(())
    }
}

impl FileConfig {
    /// Reads and parses `path`; a missing path means all defaults.
    pub fn load(path: Option<&Path>) -> anyhow::Result<Self> {
        let Some(path) = path else {
            return Ok(Self::default());
        };
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config file {}", path.display()))?;
        let mut f: Self = toml::from_str(&text)
            .with_context(|| format!("invalid config file {}", path.display()))?;
        f.train_select_given = toml::from_str::<toml::Table>(&text).is_ok_and(|t| {
            t.get("train")
                .and_then(|t| t.as_table())
                .is_some_and(|t| t.contains_key("select"))
        });
        // Certificates and password files named relative to the config file's directory
        // (secrets: `$CREDENTIALS_DIRECTORY` first, for systemd `LoadCredential=`).
        // (Absolute, so that a resolved config written elsewhere, e.g. by `fsrl train`, still
        // names the same files.)
        let abs = std::path::absolute(path)
            .with_context(|| format!("cannot resolve the path {}", path.display()))?;
        f.transport
            .zenoh
            .resolve_paths(abs.parent().unwrap_or(Path::new("/")));
        Ok(f)
    }

    /// The file's own `[train] select`, when it said one ([`select_rule`]'s `file_choice`).
    pub fn select_choice(&self) -> Option<Select> {
        self.train_select_given.then_some(self.train.select)
    }

    /// Validates everything at once.
    /// A method's own training settings (`fsrl-plan`'s planning: `Method::train_config`) are
    /// written into the resolved `[train]`, so that the run's config, checkpoints and model
    /// files say how the policy decides.
    pub fn resolve(mut self, extra_problems: Vec<String>) -> Result<Resolved, ConfigError> {
        let mut problems = extra_problems;
        let method = match self.run.method.parse::<Method>() {
            Ok(m) => {
                // The method's preset; the snapshot rule as [`select_rule`] decides it for the
                // file alone (a distributed run's launcher decides again for its mode).
                let choice = self.select_choice();
                let base = std::mem::take(&mut self.train);
                self.train = m.train_config(&base);
                self.train.select = select_rule(m, &base, choice, Mode::SingleProcess, None);
                Some(m)
            }
            Err(e) => {
                problems.push(e.to_string());
                None
            }
        };
        let setting = match self.sim.resolve_settings(&[self.run.setting.as_str()]) {
            Ok(s) => Some(s[0]),
            Err(e) => {
                problems.extend(e.problems);
                None
            }
        };
        // A run among walls is scored on its own setting unless the file names others: the
        // paper's six are another world for it (and 3,000 episodes per report for nothing).
        if let Some(s) = setting.filter(|s| !s.is_paper()) {
            if self.evaluator.settings == EvaluatorSection::default().settings {
                self.evaluator.settings = vec![s.name().to_string()];
            }
        }
        problems.extend(self.train.problems());
        if let Err(e) = proto::RunId::new(self.run.id.as_str()) {
            problems.push(format!("run.id `{}`: {e}", self.run.id));
        }
        for name in &self.evaluator.settings {
            if let Err(e) = name.parse::<Setting>() {
                problems.push(format!("evaluator.settings: {e}"));
            }
        }
        if self.evaluator.episodes_per_setting == 0 {
            problems.push("evaluator.episodes_per_setting must be at least 1".into());
        }
        if self.learner.in_flight_per_actor == 0 {
            problems.push("learner.in_flight_per_actor must be at least 1".into());
        }
        if self.sim.humans.count == 0 && method.is_some_and(|m| m.net().is_some()) {
            problems.push("sim.humans.count must be at least 1 for a learned policy".into());
        }
        match (method, setting) {
            (Some(method), Some(setting)) if problems.is_empty() => Ok(Resolved {
                method,
                setting,
                file: self,
            }),
            _ => Err(ConfigError { problems }),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The rules: what decides a run's snapshot choice and replay ratio, each in one place.

/// How a run trains: as processes (`fsrl train`'s default: learner, actors, evaluator) or in
/// one process (`--single-process`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    SingleProcess,
    Distributed,
}

/// The snapshot-selection rule (`[train] select`) of a run of `method`; every command asks
/// here. In order: a resumed run keeps its own (`resumed`: the rule in its `config.toml` or
/// checkpoint); else the file's own choice (`file_choice`: the file said `[train] select`);
/// else the method's preset (`Method::train_config`: `fsrl-plan` chooses by
/// `revalidated-return`);
/// else the mode's default: [`Select::DISTRIBUTED_DEFAULT`] for processes (Experiments 26–27),
/// `TrainConfig`'s own for one process. `base` is the file's `[train]`, with or without the
/// method's preset (applying it twice changes nothing). (A distributed run without its
/// evaluator validates nothing and so keeps its last weights: `fsrl train --no-evaluator`.)
pub fn select_rule(
    method: Method,
    base: &TrainConfig,
    file_choice: Option<Select>,
    mode: Mode,
    resumed: Option<Select>,
) -> Select {
    if let Some(s) = resumed.or(file_choice) {
        return s;
    }
    let preset = method.train_config(base).select;
    match mode {
        Mode::Distributed if preset == TrainConfig::default().select => Select::DISTRIBUTED_DEFAULT,
        _ => preset,
    }
}

/// Where a run's replay ratio came from (for its errors).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RatioSource {
    /// `--replay-ratio`.
    Flag,
    /// The resumed run's own `config.toml` (or checkpoint).
    Started,
    /// The run's config file.
    File,
    /// Nothing chose: the mode's default.
    Default,
}

/// The replay ratio (`train.rl.replay_ratio`; `None`: the fixed schedule of
/// `train.rl.batches_per_episode` updates per episode) of a run; every command asks here. For
/// processes: `--replay-ratio` (`flag`; `Some(None)` is `fixed`), else a resumed run's own
/// (`resumed`, so that it resumes to its own schedule), else the file's (`file`), else
/// [`ReplayRatio::LOCAL_DEFAULT`] (Experiment 18: level with the shipped models in about half
/// the time of one process). One process runs the fixed schedule only: bounds from the flag,
/// the file or the resumed run are refused, the `Err` naming where they came from.
pub fn replay_ratio(
    mode: Mode,
    flag: Option<Option<ReplayRatio>>,
    resumed: Option<Option<ReplayRatio>>,
    file: Option<ReplayRatio>,
) -> Result<(Option<ReplayRatio>, RatioSource), RatioSource> {
    match mode {
        Mode::Distributed => Ok(match (flag, resumed, file) {
            (Some(r), _, _) => (r, RatioSource::Flag),
            (None, Some(r), _) => (r, RatioSource::Started),
            (None, None, Some(r)) => (Some(r), RatioSource::File),
            (None, None, None) => (Some(ReplayRatio::LOCAL_DEFAULT), RatioSource::Default),
        }),
        Mode::SingleProcess => match (flag, resumed, file) {
            (Some(Some(_)), _, _) => Err(RatioSource::Flag),
            (_, _, Some(_)) => Err(RatioSource::File),
            (_, Some(Some(_)), _) => Err(RatioSource::Started),
            (Some(None), _, None) => Ok((None, RatioSource::Flag)),
            (None, _, None) => Ok((None, RatioSource::Default)),
        },
    }
}

/// The problems of a run's `[train]` once its replay ratio is set (a bad `--replay-ratio`, or a
/// bad `train.rl.replay_ratio` in a resumed run's own `config.toml`), as one error naming
/// `whence`; nothing when it is sound.
pub fn check_train(train: &TrainConfig, whence: &str) -> anyhow::Result<()> {
    let problems = train.problems();
    if problems.is_empty() {
        return Ok(());
    }
    anyhow::bail!("{whence}: {}", problems.join("; "))
}

/// On `resume`, the config the run in `out` was started with (its `config.toml`), if it has
/// one.
pub fn started_config(out: &Path, resume: bool) -> anyhow::Result<Option<FileConfig>> {
    let started = out.join("config.toml");
    if !(resume && started.exists()) {
        return Ok(None);
    }
    FileConfig::load(Some(&started))
        .with_context(|| {
            format!(
                "{} (the run's own config) is not readable",
                started.display()
            )
        })
        .map(Some)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_are_rejected_with_their_name() {
        let err = toml::from_str::<FileConfig>("[sim]\ndt = 0.1\n").unwrap_err();
        assert!(err.to_string().contains("unknown field `dt`"), "{err}");
        let err = toml::from_str::<FileConfig>("[sim.robot]\nradius_m = \"big\"\n").unwrap_err();
        assert!(err.to_string().contains("radius_m"), "{err}");
        let err = toml::from_str::<FileConfig>("[train.rl]\nepisodes = 5\nlr = 0.1\n").unwrap_err();
        assert!(err.to_string().contains("unknown field `lr`"), "{err}");
    }

    #[test]
    fn partial_tables_keep_the_other_defaults() {
        let c: FileConfig = toml::from_str(
            "[sim]\ndt_s = 0.1\n[sim.humans]\ncount = 5\n[train.rl]\nepisodes = 7\n",
        )
        .unwrap();
        assert_eq!(c.sim.dt_s, 0.1);
        assert_eq!(c.sim.humans.count, 5);
        assert_eq!(c.sim.humans.radius_m, 0.3);
        assert_eq!(c.train.rl.episodes, 7);
        assert_eq!(c.train.rl.batch_size, 100);
    }

    #[test]
    fn the_resolved_config_round_trips_through_toml() {
        let c = FileConfig::default();
        let text = toml::to_string(&c).unwrap();
        let back: FileConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, c);
    }

    /// A walled run's evaluator scores its own setting by default; a paper run's the six; a
    /// list given in the file is kept.
    #[test]
    fn a_walled_run_is_evaluated_on_its_own_setting() {
        let mut c = FileConfig::default();
        c.run.setting = "corridor".into();
        let r = c.clone().resolve(Vec::new()).unwrap();
        assert_eq!(r.file.evaluator.settings, vec!["corridor".to_string()]);
        let paper = FileConfig::default().resolve(Vec::new()).unwrap();
        assert_eq!(paper.file.evaluator.settings.len(), 6);
        c.evaluator.settings = vec!["env1-visible".into(), "corridor".into()];
        let r = c.resolve(Vec::new()).unwrap();
        assert_eq!(r.file.evaluator.settings, vec!["env1-visible", "corridor"]);
    }

    /// `--method fsrl-plan` writes its planning into the resolved `[train]` (and so into the
    /// run's config and model files); its own planning in a config is kept; `fsrl` plans never.
    #[test]
    fn fsrl_plan_resolves_with_its_decision_time_planning() {
        let mut c = FileConfig::default();
        c.run.method = "fsrl-plan".into();
        let r = c.clone().resolve(Vec::new()).unwrap();
        assert_eq!(r.method, Method::FsrlPlan);
        let t = &r.file.train;
        assert_eq!(
            (t.planning_top_k, t.planning_breadth, t.planning_in_training),
            (
                policy::method::FSRL_PLAN_TOP_K,
                policy::method::FSRL_PLAN_BREADTH,
                false
            )
        );
        let text = toml::to_string(&r.file).unwrap();
        assert!(
            text.contains("planning_top_k = 8") && text.contains("select = \"revalidated-return\""),
            "{text}"
        );
        c.train.planning_top_k = 3;
        assert_eq!(
            c.clone()
                .resolve(Vec::new())
                .unwrap()
                .file
                .train
                .planning_top_k,
            3
        );
        c.run.method = "fsrl".into();
        c.train.planning_top_k = 0;
        assert_eq!(
            c.resolve(Vec::new()).unwrap().file.train,
            Default::default()
        );
    }

    #[test]
    fn every_problem_of_a_run_is_reported() {
        let mut c = FileConfig::default();
        c.run.method = "dqn".into();
        c.run.setting = "env4-visible".into();
        c.train.gamma = 2.0;
        c.sim.dt_s = 0.0;
        let err = c
            .resolve(vec!["--rl-episodes must be at least 1".into()])
            .unwrap_err();
        assert_eq!(err.problems.len(), 5, "{err}");
    }

    /// The config of `method` from the file `cfg` (if any), resolved as `fsrl train` does.
    fn resolved(cfg: Option<&Path>, method: &str) -> Resolved {
        let mut f = FileConfig::load(cfg).unwrap();
        f.run.method = method.into();
        f.resolve(Vec::new()).unwrap()
    }

    /// A distributed run's choice and ratio, as `fsrl train` makes them.
    fn for_processes(
        cfg: Option<&Path>,
        method: &str,
        out: &Path,
        resume: bool,
        flag: Option<Option<ReplayRatio>>,
    ) -> anyhow::Result<TrainConfig> {
        let mut r = resolved(cfg, method);
        r.for_processes(out, resume, flag, true)?;
        Ok(r.file.train)
    }

    /// A distributed run chooses by `revalidated-return` (`Select::DISTRIBUTED_DEFAULT`) unless its config (or its method) chooses,
    /// and a resumed run by the rule it was started with (Experiments 26–27); one process by
    /// `TrainConfig`'s own unless the file or the method chooses.
    #[test]
    fn a_runs_choice_comes_from_its_own_config_the_file_the_method_or_the_default() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let select = |cfg: Option<&Path>, method: &str, resume: bool| {
            for_processes(cfg, method, &out, resume, None)
                .unwrap()
                .select
        };
        assert_eq!(select(None, "fsrl", false), Select::DISTRIBUTED_DEFAULT);
        assert_eq!(Select::DISTRIBUTED_DEFAULT, Select::RevalidatedReturn);
        assert_eq!(resolved(None, "fsrl").file.train.select, Select::LowDisc);
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "[train]\nselect = \"low-disc\"\n").unwrap();
        let c = Some(cfg.as_path());
        assert_eq!(select(c, "fsrl", false), Select::LowDisc);
        assert_eq!(
            select(c, "fsrl-plan", false),
            Select::LowDisc,
            "the file's own choice stays"
        );
        assert_eq!(resolved(c, "fsrl-plan").file.train.select, Select::LowDisc);
        assert_eq!(select(None, "fsrl-plan", false), Select::RevalidatedReturn);
        assert_eq!(
            resolved(None, "fsrl-plan").file.train.select,
            Select::RevalidatedReturn
        );
        // A run started with low-disc resumes with it.
        std::fs::create_dir_all(&out).unwrap();
        std::fs::copy(&cfg, out.join("config.toml")).unwrap();
        assert_eq!(select(None, "fsrl", true), Select::LowDisc);
        // A run started with best-return (before issue 54) keeps it, for both methods.
        std::fs::write(
            out.join("config.toml"),
            "[train]\nselect = \"best-return\"\n",
        )
        .unwrap();
        assert_eq!(select(None, "fsrl", true), Select::BestReturn);
        assert_eq!(select(None, "fsrl-plan", true), Select::BestReturn);
        // Without the evaluator: its last weights.
        let mut r = resolved(c, "fsrl");
        r.for_processes(&out, false, None, false).unwrap();
        assert_eq!(r.file.train.select, Select::Last);
    }

    #[test]
    fn a_distributed_runs_replay_ratio_comes_from_the_flag_its_own_config_the_file_or_the_default()
    {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("run");
        let ratio = |cfg: Option<&Path>, resume: bool, flag| {
            for_processes(cfg, "fsrl", &out, resume, flag).map(|t| t.rl.replay_ratio)
        };
        let bounds = |min, max| Some(ReplayRatio { min, max });
        assert_eq!(
            ratio(None, false, None).unwrap(),
            Some(ReplayRatio::LOCAL_DEFAULT)
        );
        let cfg = dir.path().join("c.toml");
        std::fs::write(&cfg, "[train.rl]\nreplay_ratio = { min = 2, max = 9 }\n").unwrap();
        let c = Some(cfg.as_path());
        assert_eq!(ratio(c, false, None).unwrap(), bounds(2.0, 9.0));
        assert_eq!(ratio(c, false, Some(None)).unwrap(), None);
        assert_eq!(
            ratio(None, false, Some(bounds(5.0, 6.0))).unwrap(),
            bounds(5.0, 6.0)
        );
        // One process: the fixed schedule only; bounds are refused, naming where they came from.
        let one = |flag, resumed, file| replay_ratio(Mode::SingleProcess, flag, resumed, file);
        assert_eq!(one(None, None, None), Ok((None, RatioSource::Default)));
        assert_eq!(one(Some(None), None, None), Ok((None, RatioSource::Flag)));
        assert_eq!(
            one(Some(bounds(1.0, 2.0)), None, None),
            Err(RatioSource::Flag)
        );
        assert_eq!(
            one(Some(None), None, bounds(1.0, 2.0)),
            Err(RatioSource::File)
        );
        assert_eq!(
            one(None, Some(bounds(1.0, 2.0)), None),
            Err(RatioSource::Started)
        );

        // A run started with the fixed schedule resumes with it, whatever today's default.
        std::fs::create_dir_all(&out).unwrap();
        let started = resolved(None, "fsrl");
        assert_eq!(started.file.train.rl.replay_ratio, None);
        std::fs::write(
            out.join("config.toml"),
            toml::to_string(&started.file).unwrap(),
        )
        .unwrap();
        assert_eq!(ratio(None, true, None).unwrap(), None);
        assert_eq!(
            ratio(None, true, Some(Some(ReplayRatio::LOCAL_DEFAULT))).unwrap(),
            Some(ReplayRatio::LOCAL_DEFAULT)
        );
        std::fs::write(out.join("config.toml"), "[train.rl]\nnot_a_key = 1\n").unwrap();
        let e = ratio(None, true, None).unwrap_err();
        assert!(format!("{e:#}").contains("the run's own config"), "{e:#}");
    }
}
