//! `fsrl learner`, `fsrl actor`, `fsrl evaluator`: the three processes of a distributed run.
//! Each takes a config file (see `deploy/`) plus CLI overrides and connects over zenoh with
//! explicit endpoints (and iceoryx2 shared memory for the data plane when configured).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use proto::{Role, SenderId};
use transport::{DataPlane, Transport, ZenohMode};

use crate::config::{FileConfig, Resolved, RunOverrides};

/// Options every role takes.
#[derive(Debug, Clone, clap::Args)]
pub struct CommonArgs {
    #[command(flatten)]
    pub run: RunOverrides,
    /// Run id [default: from the config, else "local"]
    #[arg(long)]
    pub run_id: Option<String>,
    /// zenoh endpoint to listen on (repeatable), e.g. tcp/127.0.0.1:7447
    #[arg(long)]
    pub listen: Vec<String>,
    /// zenoh endpoint to connect to (repeatable): the learner's or a router's
    #[arg(long)]
    pub connect: Vec<String>,
    /// zenoh mode: peer or client (of a router)
    #[arg(long)]
    pub mode: Option<String>,
    /// Data plane: zenoh or iceoryx2
    #[arg(long)]
    pub data_plane: Option<String>,
    /// Learner run directory (checkpoints, write-ahead log) [default: runs/<run id>]
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
}

impl CommonArgs {
    /// The file config with every override applied, validated.
    pub fn resolve(&self, extra: impl FnOnce(&mut FileConfig)) -> anyhow::Result<Resolved> {
        let mut f = self.run.load()?;
        let mut problems = Vec::new();
        if let Some(v) = &self.run_id {
            f.run.id = v.clone();
        }
        if !self.listen.is_empty() {
            f.transport.zenoh.listen = self.listen.clone();
        }
        if !self.connect.is_empty() {
            f.transport.zenoh.connect = self.connect.clone();
        }
        match self.mode.as_deref() {
            None => {}
            Some("peer") => f.transport.zenoh.mode = ZenohMode::Peer,
            Some("client") => {
                f.transport.zenoh.mode = ZenohMode::Client;
                if self.listen.is_empty() {
                    f.transport.zenoh.listen.clear();
                }
            }
            Some(m) => problems.push(format!("--mode must be peer or client, got `{m}`")),
        }
        match self.data_plane.as_deref() {
            None => {}
            Some("zenoh") => f.transport.data_plane = DataPlane::Zenoh,
            Some("iceoryx2") => f.transport.data_plane = DataPlane::Iceoryx2,
            Some(d) => problems.push(format!("--data-plane must be zenoh or iceoryx2, got `{d}`")),
        }
        if let Some(v) = &self.run_dir {
            f.learner.run_dir = Some(v.clone());
        }
        extra(&mut f);
        if f.run.method == "orca" {
            problems.push("method orca has no network: there is nothing to train".into());
        }
        Ok(f.resolve(problems)?)
    }
}

/// Installs SIGINT/SIGTERM handling: the returned flag is raised on the first signal.
pub fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    ctrlc::set_handler(move || {
        if s.swap(true, Ordering::SeqCst) {
            eprintln!("second signal: exiting at once");
            std::process::exit(130);
        }
    })
    .context("cannot install the signal handler")?;
    Ok(stop)
}

/// Opens the transport, retrying (and saying so) while it cannot.
pub fn open_transport(
    r: &Resolved,
    sender: SenderId,
    stop: &AtomicBool,
) -> anyhow::Result<Transport> {
    let cfg = r.file.transport.for_sender(&r.file.run.id, sender)?;
    let mut wait = Duration::from_millis(500);
    loop {
        match Transport::open(cfg.clone()) {
            Ok(t) => return Ok(t),
            // A configuration problem (e.g. an unreadable certificate) does not go away.
            Err(e @ transport::TransportError::Config(_)) => {
                return Err(e).with_context(|| format!("{sender}: cannot open the transport"))
            }
            Err(e) => {
                eprintln!(
                    "{sender}: cannot open the transport (listen {:?}, connect {:?}): {e}; retrying in {:.1} s",
                    cfg.zenoh.listen,
                    cfg.zenoh.connect,
                    wait.as_secs_f64()
                );
                std::thread::sleep(wait);
                wait = (wait * 2).min(Duration::from_secs(10));
                if stop.load(Ordering::SeqCst) {
                    bail!("stopped before the transport could be opened");
                }
            }
        }
    }
}

#[derive(Debug, clap::Args)]
pub struct LearnerArgs {
    #[command(flatten)]
    pub common: CommonArgs,
}

pub fn learner(args: LearnerArgs) -> anyhow::Result<()> {
    let stop = stop_flag()?;
    let r = args.common.resolve(|_| {})?;
    // The learner's update threads: every core unless the config says otherwise.
    let threads = match r.file.learner.threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("cannot start the learner's update threads")?;
    let t = open_transport(&r, SenderId::new(Role::Learner, 0), &stop)?;
    tracing::info!(threads, "learner update threads");
    let opts = learner::process::LearnerOptions {
        run_dir: r.run_dir(),
        run_id: r.file.run.id.clone(),
        in_flight_per_actor: r.file.learner.in_flight_per_actor,
        metrics_interval: Duration::from_millis(r.file.learner.metrics_interval_ms),
        linger: Duration::from_millis(r.file.learner.linger_ms),
    };
    tracing::info!(run = %r.file.run.id, method = %r.method, setting = %r.setting, dir = %opts.run_dir.display(), "learner starting");
    let exit = learner::process::run(&t, &r.spec(), &opts, &stop)?;
    tracing::info!(?exit, "learner done");
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct ActorArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Actor index, unique in the run [default: from the config]
    #[arg(long)]
    pub id: Option<u32>,
}

pub fn actor(args: ActorArgs) -> anyhow::Result<()> {
    let stop = stop_flag()?;
    let r = args.common.resolve(|f| {
        if let Some(id) = args.id {
            f.actor.id = id;
        }
    })?;
    let id = r.file.actor.id;
    let t = open_transport(&r, SenderId::new(Role::Actor, id), &stop)?;
    let exit = actor::run(&t, &r.spec(), id, &stop)?;
    tracing::info!(actor = id, ?exit, "actor done");
    Ok(())
}

#[derive(Debug, clap::Args)]
pub struct EvaluatorArgs {
    #[command(flatten)]
    pub common: CommonArgs,
    /// Evaluate this checkpoint or model file (.fsrlm; the kind is read from its first bytes)
    /// and exit (no transport).
    #[arg(long, visible_alias = "model")]
    pub checkpoint: Option<PathBuf>,
    /// Evaluate a snapshot every N RL episodes (0: only the final weights)
    #[arg(long)]
    pub every: Option<u64>,
    /// Test episodes per setting [default: 500]
    #[arg(long)]
    pub episodes: Option<u32>,
    /// Where to write reports [default: <run dir>/eval]
    #[arg(long)]
    pub out_dir: Option<PathBuf>,
}

pub fn evaluator(args: EvaluatorArgs) -> anyhow::Result<()> {
    let stop = stop_flag()?;
    let r = args.common.resolve(|f| {
        if let Some(v) = args.every {
            f.evaluator.every_episodes = v;
        }
        if let Some(v) = args.episodes {
            f.evaluator.episodes_per_setting = v;
        }
        if let Some(v) = &args.out_dir {
            f.evaluator.out_dir = Some(v.clone());
        }
    })?;
    let e = &r.file.evaluator;
    let settings = r.file.sim.resolve_settings(&e.settings)?;
    let opts = evaluator::process::EvaluatorOptions {
        every_episodes: e.every_episodes,
        episodes_per_setting: e.episodes_per_setting,
        seed_start: e.seed_start,
        settings: settings.clone(),
        threads: e.threads.max(1),
        out_dir: e
            .out_dir
            .clone()
            .unwrap_or_else(|| r.run_dir().join("eval")),
        final_report: e.final_report,
    };
    if let Some(path) = &args.checkpoint {
        // Offline: the checkpoint or model says what it is.
        let (model, _) = learner::model::load_policy(path)?;
        let subject = evaluator::Subject::learned(model.method, &model.net, &model.train);
        // The simulator config the policy was trained with (the method's switches applied).
        let base = model.sim.clone();
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let results = evaluator::evaluate(
            subject,
            &base,
            &settings,
            opts.seed_start,
            opts.episodes_per_setting,
            threads,
        )?;
        let trained = model.counters.rl_episodes;
        let report = evaluator::process::report(&results, trained, true);
        std::fs::create_dir_all(&opts.out_dir)
            .with_context(|| format!("cannot create {}", opts.out_dir.display()))?;
        let md = format!(
            "{}\nTrained on {} (run seed {}).\n",
            evaluator::process::markdown(
                &report,
                model.method.name(),
                model.counters.policy_version,
            ),
            model.setting,
            model.run_seed
        );
        std::fs::write(
            opts.out_dir.join("report.json"),
            serde_json::to_string_pretty(&report)?,
        )?;
        std::fs::write(opts.out_dir.join("report.md"), &md)?;
        println!("{md}");
        println!("reports written to {}", opts.out_dir.display());
        return Ok(());
    }
    let t = open_transport(&r, SenderId::new(Role::Evaluator, 0), &stop)?;
    // Every validated snapshot is kept as a model file (before its validation line), so the
    // selection rules, `fsrl eval RUN` and `fsrl export-model RUN` work as on a single-process run.
    let spec = r.spec();
    let snapshots = lab::select::snapshot_dir(&opts.out_dir);
    let keep = |net: &policy::ValueNet, version: u64, rl_episodes: u64| -> Result<(), String> {
        std::fs::create_dir_all(&snapshots)
            .map_err(|e| format!("cannot create {}: {e}", snapshots.display()))?;
        let path = lab::select::snapshot_path(&opts.out_dir, rl_episodes);
        learner::model::Model::from_snapshot(&spec, &r.file.run.id, net, version, rl_episodes)
            .and_then(|m| m.save(&path))
            .map_err(|e| format!("cannot keep the snapshot {}: {e}", path.display()))
    };
    let keep_snapshots = spec.train.select != policy::method::Select::Last;
    let keeper: Option<evaluator::process::KeepSnapshot<'_>> = keep_snapshots.then_some(&keep);
    match evaluator::process::run(&t, &spec, &opts, &stop, keeper)? {
        evaluator::process::EvaluatorExit::Finished(Some(rep)) => {
            println!("{}", evaluator::process::markdown(&rep, r.method.name(), 0));
        }
        evaluator::process::EvaluatorExit::Finished(None)
        | evaluator::process::EvaluatorExit::Stopped => {}
    }
    Ok(())
}
