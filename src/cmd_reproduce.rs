//! `fsrl reproduce`: the paper's grid in one command. Trains methods × settings × seeds (each
//! run in its own setting, as the paper does), exports every finished run as a model file,
//! evaluates each model on the test seeds of its setting and ORCA on all six, and writes one
//! report beside the paper's numbers (`fsrl compare`, in this process).
//!
//! Every step is a child process of this same executable (`fsrl train`: a learner, actors and
//! an evaluator, or `fsrl train --single-process` with `--single-process`; `fsrl export-model`,
//! `fsrl eval`); this module only decides what to run. A run directory
//! with `report.json` is finished, one with `checkpoints/latest.ckpt` alone is resumed, any other
//! is removed and started again; a model at least as new as its run's `report.json` and an
//! `eval.json` at least as new as its model (same episodes, same setting) are kept. Running the
//! same command again therefore goes on where it stopped.

use std::ffi::OsString;
use std::os::unix::process::CommandExt as _;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use lab::grid::{
    cells, describe, duration_text, eval_is_current, held_by_other, model_is_current, plan,
    rough_eval_s, rough_train_s, shard_of, Calibration, Cell, Layout, Training,
};
use policy::method::Method;
use sim::Setting;

use crate::config::{FileConfig, ReplayRatioArg};

#[derive(Debug, clap::Args)]
pub struct ReproduceArgs {
    /// Run configuration of every run ([train] schedule, [sim] simulator) [default: the
    /// built-in defaults: the short schedule of configs/fast.toml; the paper's is
    /// configs/paper.toml]
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Train each run in one process (`fsrl train --single-process`: bit-for-bit reproducible,
    /// the path that trained the shipped models) instead of learner, actors and evaluator
    #[arg(long)]
    pub single_process: bool,
    /// Actor processes of each distributed run
    #[arg(long, default_value_t = 2)]
    pub actors: u32,
    /// Updates per RL episode of each distributed run (`fsrl train --replay-ratio`): `MIN,MAX`
    /// or `fixed` [default: the config's train.rl.replay_ratio, else 4,20]
    #[arg(long, value_name = "MIN,MAX|fixed", allow_hyphen_values = true, value_parser = ReplayRatioArg::parse)]
    pub replay_ratio: Option<ReplayRatioArg>,
    /// Train only shard I of N of the grid (0 ≤ I < N; run k of the grid, in its order, belongs
    /// to shard k mod N), for a cluster scheduler's array job. Without it: from
    /// SLURM_ARRAY_TASK_ID − SLURM_ARRAY_TASK_MIN of SLURM_ARRAY_TASK_COUNT, or Kubernetes'
    /// JOB_COMPLETION_INDEX of FSRL_SHARDS; otherwise the whole grid. A shard writes no report:
    /// `fsrl reproduce --no-train` over the shared directories writes it
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Methods to train, comma-separated, run in this order
    #[arg(long, value_delimiter = ',', default_values = ["lstm-rl", "sarl", "fsrl"])]
    pub methods: Vec<String>,
    /// Settings, comma-separated, in this order; each run is trained and evaluated in its own
    /// setting [default: all six]
    #[arg(long, value_delimiter = ',')]
    pub settings: Vec<String>,
    /// Run seeds, comma-separated, in this order
    #[arg(long, value_delimiter = ',', default_values_t = [0u64, 1, 2])]
    pub seeds: Vec<u64>,
    /// Run directories: RUNS/<method>-<setting>-s<seed>; evaluations in RUNS/eval/
    #[arg(long, default_value = "runs/reproduce")]
    pub runs: PathBuf,
    /// Model files: MODELS/<method>-<setting>-s<seed>.fsrlm
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Test episodes of each evaluation (seeds from 1000)
    #[arg(long, default_value_t = 500)]
    pub episodes: u32,
    /// Report directory (compare.md, compare.csv, compare.json) [default: RUNS/report]
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print the plan (finished, to resume, to train) and the estimated time; run nothing
    #[arg(long)]
    pub dry_run: bool,
    /// Train nothing: export, evaluate and report the runs that are finished
    #[arg(long)]
    pub no_train: bool,
}

// ---------------------------------------------------------------------------------------------
// The grid.

/// What the command line asks for, validated.
pub struct Grid {
    /// The config file, its `train.rl.replay_ratio` the one the runs are trained with (what
    /// `fsrl train` resolves for them: `--replay-ratio`, else the file's, else the default of
    /// distributed runs), so that a run on disk is compared with what it was trained with.
    pub file: FileConfig,
    pub methods: Vec<Method>,
    pub settings: Vec<Setting>,
    pub seeds: Vec<u64>,
}

/// Reads the config and checks every name and number before anything starts, all problems
/// reported together.
pub fn grid(args: &ReproduceArgs) -> anyhow::Result<Grid> {
    let mut file = FileConfig::load(args.config.as_deref())?;
    let mut problems = Vec::new();
    if args.actors == 0 {
        problems.push("--actors must be at least 1".to_string());
    }
    match args.replay_ratio {
        Some(ReplayRatioArg(Some(_))) if args.single_process => problems.push(
            "--replay-ratio MIN,MAX needs distributed runs; --single-process trains the fixed schedule".to_string(),
        ),
        Some(ReplayRatioArg(r)) => file.train.rl.replay_ratio = r,
        // `fsrl train`'s default for a distributed run (a single-process one refuses bounds
        // from the file, below).
        None if !args.single_process => {
            let rl = &mut file.train.rl;
            rl.replay_ratio = rl
                .replay_ratio
                .or(Some(policy::method::ReplayRatio::LOCAL_DEFAULT));
        }
        None => {}
    }
    if !args.single_process {
        // `fsrl train`'s choice for a distributed run (Experiments 26–27), so that a finished
        // run is compared with what it was trained with.
        file.train.select = file.distributed_select();
    }
    if args.single_process && file.train.rl.replay_ratio.is_some() {
        problems.push(
            "train.rl.replay_ratio (the adaptive mode) needs distributed runs; --single-process trains the fixed schedule: drop one of the two".to_string(),
        );
    }
    let mut methods = Vec::new();
    for name in &args.methods {
        match name.parse::<Method>() {
            Ok(Method::Orca) => problems.push(
                "--methods: orca is not trained (its row is always in the report)".to_string(),
            ),
            Ok(m) if methods.contains(&m) => problems.push(format!("--methods lists {m} twice")),
            Ok(m) => methods.push(m),
            Err(e) => problems.push(format!("--methods: {e}")),
        }
    }
    let names: Vec<String> = if args.settings.is_empty() {
        Setting::ALL.iter().map(|s| s.name().to_string()).collect()
    } else {
        args.settings.clone()
    };
    let settings = match file.sim.resolve_settings(&names) {
        Ok(s) => s,
        Err(e) => {
            problems.extend(e.problems);
            Vec::new()
        }
    };
    for (i, s) in settings.iter().enumerate() {
        if settings[..i].contains(s) {
            problems.push(format!("--settings lists {s} twice"));
        }
    }
    for (i, s) in args.seeds.iter().enumerate() {
        if args.seeds[..i].contains(s) {
            problems.push(format!("--seeds lists {s} twice"));
        }
    }
    if args.methods.is_empty() || args.seeds.is_empty() {
        problems.push("--methods and --seeds must name at least one each".into());
    }
    if args.episodes == 0 {
        problems.push("--episodes must be at least 1".into());
    }
    // The rest of the file (schedule, run id, ...), checked as `fsrl train` will check it.
    let mut probe = file.clone();
    probe.run.method = Method::Sarl.name().into();
    probe.run.setting = Setting::ALL[0].name().into();
    if let Err(e) = probe.resolve(Vec::new()) {
        for p in e.problems {
            if !problems.contains(&p) {
                problems.push(p);
            }
        }
    }
    if !problems.is_empty() {
        return Err(sim::ConfigError { problems }.into());
    }
    Ok(Grid {
        file,
        methods,
        settings,
        seeds: args.seeds.clone(),
    })
}

// ---------------------------------------------------------------------------------------------
// Child processes.

/// Runs steps as child processes of this executable, one at a time, forwarding Ctrl-C.
struct Runner {
    exe: PathBuf,
    interrupts: Arc<AtomicU32>,
}

impl Runner {
    fn new() -> anyhow::Result<Self> {
        let interrupts = Arc::new(AtomicU32::new(0));
        {
            let interrupts = interrupts.clone();
            ctrlc::set_handler(move || {
                if interrupts.fetch_add(1, Ordering::SeqCst) == 0 {
                    eprintln!("\ninterrupted: stopping the current step (fsrl train writes a checkpoint first); Ctrl-C again to stop it at once");
                }
            })
            .context("cannot install the Ctrl-C handler")?;
        }
        Ok(Self {
            exe: std::env::current_exe().context("cannot find the fsrl executable")?,
            interrupts,
        })
    }

    fn interrupted(&self) -> bool {
        self.interrupts.load(Ordering::SeqCst) > 0
    }

    /// Stops the grid after an interrupt, saying how to go on.
    fn stop(&self, what: &str) -> ! {
        let argv: Vec<String> = std::env::args_os()
            .map(|a| a.to_string_lossy().into_owned())
            .collect();
        eprintln!(
            "stopped {what}. Finished steps are kept and an interrupted training resumes from its checkpoint: to continue, run the same command again:\n  {}\n(add --no-train for a report of what is finished)",
            argv.join(" ")
        );
        std::process::exit(130)
    }

    /// Runs `fsrl ARGS`, its output on our stderr. The child has its own process group, so a
    /// terminal's Ctrl-C reaches only us and we forward each one: the first makes `fsrl train`
    /// checkpoint and exit, a second stops it at once. After an interrupt the grid stops.
    fn step(&self, tag: &str, what: &str, dir: &Path, args: &[OsString]) -> anyhow::Result<()> {
        if self.interrupted() {
            self.stop(&format!("before {tag}: {what}"));
        }
        let mut child = Command::new(&self.exe)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::from(std::io::stderr()))
            .stderr(Stdio::from(std::io::stderr()))
            .process_group(0)
            .spawn()
            .with_context(|| format!("{tag}: cannot start {}", self.exe.display()))?;
        let mut forwarded = 0;
        let status: ExitStatus = loop {
            if let Some(status) = child.try_wait()? {
                break status;
            }
            let n = self.interrupts.load(Ordering::SeqCst);
            if n > forwarded {
                forwarded = n;
                // SAFETY: kill(2) on the pid of our child, which has not been reaped (try_wait
                // above saw it running and only this thread waits for it).
                unsafe {
                    libc::kill(child.id() as libc::pid_t, libc::SIGINT);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        if self.interrupted() {
            self.stop(&format!("during {tag}: {what}"));
        }
        if !status.success() {
            bail!(
                "{tag}: {what} failed ({status}); its directory: {}. The grid stopped here; fix the cause and run the same command again (finished runs are skipped)",
                dir.display()
            );
        }
        Ok(())
    }
}

fn os(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    args.iter().map(|a| a.as_ref().to_os_string()).collect()
}

pub fn run(args: ReproduceArgs) -> anyhow::Result<()> {
    let grid = grid(&args)?;
    let layout = Layout {
        runs: args.runs.clone(),
        models: args.models.clone(),
    };
    let shard = shard_of(args.shard.as_deref(), &|k| std::env::var(k).ok())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut planned = plan(
        &cells(&grid.methods, &grid.settings, &grid.seeds),
        &layout,
        &grid.file.sim,
        &grid.file.train,
        args.episodes,
    );
    if let Some(sh) = shard {
        planned = planned
            .into_iter()
            .enumerate()
            .filter(|(k, _)| sh.holds(*k))
            .map(|(_, p)| p)
            .collect();
        if !args.dry_run && !args.no_train {
            let busy: Vec<String> = planned
                .iter()
                .filter_map(|p| held_by_other(&p.run_dir))
                .collect();
            if !busy.is_empty() {
                bail!(
                    "shard {}/{}: runs of this shard are being trained elsewhere (two shards must not share a run; same --shard twice?):\n  - {}",
                    sh.index,
                    sh.count,
                    busy.join("\n  - ")
                );
            }
        }
    }
    let train = &grid.file.train;
    let orca_dir = layout.orca_eval_dir();
    let orca_current = eval_is_current(&orca_dir, &Setting::ALL, args.episodes, None);
    let report_dir = args.out.clone().unwrap_or_else(|| args.runs.join("report"));
    let table = describe(&planned, orca_current, train, args.episodes, args.no_train);
    let header = format!(
        "fsrl reproduce: {} seeds × {} settings × {} methods = {} runs (seed-major, then setting, then method), config {}, runs in {}, models in {}, {} test episodes per evaluation\n",
        grid.seeds.len(),
        grid.settings.len(),
        grid.methods.len(),
        planned.len(),
        args.config
            .as_ref()
            .map_or("(built-in defaults)".to_string(), |c| c.display().to_string()),
        layout.runs.display(),
        layout.models.display(),
        args.episodes
    );
    let header = match shard {
        Some(sh) => format!(
            "{header}shard {}/{}: {} of the grid's runs (run k belongs to shard k mod {})\n",
            sh.index,
            sh.count,
            planned.len(),
            sh.count
        ),
        None => header,
    };
    if args.dry_run {
        print!("{header}{table}");
        return Ok(());
    }
    eprint!("{header}{table}");

    let runner = Runner::new()?;
    let mut cal = Calibration::default();
    // `--config FILE` for every child, or nothing: the children's defaults are this one's.
    let config: Vec<OsString> = match &args.config {
        Some(c) => os(&[&"--config", c]),
        None => Vec::new(),
    };
    let episodes = args.episodes.to_string();
    // ORCA's row: evaluated by the whole grid or by shard 0.
    if !orca_current && shard.is_none_or(|s| s.index == 0) {
        eprintln!("[orca] evaluating ORCA on the six settings ...");
        runner.step(
            "[orca]",
            "evaluating ORCA",
            &orca_dir,
            &[
                os(&[&"eval", &"--orca", &"--episodes", &episodes]),
                config.clone(),
                os(&[&"--out", &orca_dir]),
            ]
            .concat(),
        )?;
    }
    let mut sources = vec![orca_dir.join("eval.json")];
    let n = planned.len();
    let mut complete = planned.iter().filter(|p| p.complete()).count();
    for (i, p) in planned.iter().enumerate() {
        let tag = format!("[{}/{n}] {}", i + 1, p.name);
        if p.complete() {
            eprintln!("{tag}: finished, exported and evaluated; skipped");
            sources.push(p.eval_dir.join("eval.json"));
            continue;
        }
        let start = Instant::now();
        let Cell {
            method,
            setting,
            seed,
        } = p.cell;
        let state = Training::of(&p.run_dir);
        if state != Training::Finished {
            if args.no_train {
                eprintln!("{tag}: training not finished; skipped (--no-train)");
                continue;
            }
            if state == Training::Restart {
                eprintln!(
                    "{tag}: {} holds neither report.json nor a checkpoint (stopped during imitation); removing it",
                    p.run_dir.display()
                );
                std::fs::remove_dir_all(&p.run_dir)
                    .with_context(|| format!("cannot remove {}", p.run_dir.display()))?;
            }
            let rough = rough_train_s(method, train, state);
            eprintln!(
                "{tag}: training, {}, about {} ...",
                state.text(),
                duration_text(rough * cal.train_factor(method))
            );
            let seed_text = seed.to_string();
            let mode = if args.single_process {
                os(&[&"--single-process"])
            } else {
                let mut m = os(&[&"--actors", &args.actors.to_string()]);
                if let Some(ReplayRatioArg(r)) = args.replay_ratio {
                    let r = r.map_or("fixed".to_string(), |r| format!("{},{}", r.min, r.max));
                    m.extend(os(&[&"--replay-ratio", &r]));
                }
                m
            };
            let mut a = [os(&[&"train"]), mode, config.clone()].concat();
            a.extend(os(&[
                &"--method",
                &method.name(),
                &"--setting",
                &setting.name(),
                &"--seed",
                &seed_text,
                &"--out",
                &p.run_dir,
            ]));
            if matches!(state, Training::Resume { .. }) {
                a.push("--resume".into());
            }
            let t0 = Instant::now();
            runner.step(&tag, "training", &p.run_dir, &a)?;
            if Training::of(&p.run_dir) != Training::Finished {
                bail!(
                    "{tag}: fsrl train exited without writing {}",
                    p.run_dir.join("report.json").display()
                );
            }
            cal.record_train(method, t0.elapsed().as_secs_f64(), rough);
        }
        if !model_is_current(&p.model, &p.run_dir) {
            eprintln!("{tag}: exporting {} ...", p.model.display());
            std::fs::create_dir_all(&layout.models)
                .with_context(|| format!("cannot create {}", layout.models.display()))?;
            runner.step(
                &tag,
                "exporting the model",
                &p.run_dir,
                &os(&[&"export-model", &p.run_dir, &"--out", &p.model]),
            )?;
            if !model_is_current(&p.model, &p.run_dir) {
                bail!(
                    "{tag}: fsrl export-model did not write {}",
                    p.model.display()
                );
            }
        }
        if !eval_is_current(&p.eval_dir, &[setting], args.episodes, Some(&p.model)) {
            eprintln!("{tag}: evaluating on {episodes} test episodes of {setting} ...");
            let t0 = Instant::now();
            runner.step(
                &tag,
                "evaluating the model",
                &p.eval_dir,
                &os(&[
                    &"eval",
                    &p.model,
                    &"--settings",
                    &setting.name(),
                    &"--episodes",
                    &episodes,
                    &"--out",
                    &p.eval_dir,
                ]),
            )?;
            cal.record_eval(
                method,
                t0.elapsed().as_secs_f64(),
                rough_eval_s(method, args.episodes),
            );
        }
        sources.push(p.eval_dir.join("eval.json"));
        complete += 1;
        eprintln!(
            "{tag}: done in {}; {complete}/{n} runs complete, grid ETA {}",
            duration_text(start.elapsed().as_secs_f64()),
            duration_text(cal.eta_s(&planned[i + 1..], train, args.episodes, args.no_train))
        );
    }
    if let Some(sh) = shard {
        eprintln!(
            "shard {}/{} done: {complete} of its {n} runs complete; when every shard is done, `fsrl reproduce --no-train` with the same grid, --runs and --models writes the report",
            sh.index, sh.count
        );
        return Ok(());
    }
    eprintln!(
        "report of {} evaluated runs and ORCA → {}",
        sources.len() - 1,
        report_dir.display()
    );
    let c = lab::compare::compare(&sources, &[])?;
    println!("{}", c.markdown);
    c.write_to(&report_dir)?;
    println!(
        "written: {}/compare.md, compare.csv, compare.json",
        report_dir.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use lab::run::run_name;

    fn set(name: &str) -> Setting {
        name.parse().unwrap()
    }

    fn args(config: &Path, runs: &Path) -> ReproduceArgs {
        ReproduceArgs {
            config: Some(config.to_path_buf()),
            single_process: false,
            actors: 2,
            replay_ratio: None,
            shard: None,
            methods: vec!["sarl".into()],
            settings: Vec::new(),
            seeds: vec![0],
            runs: runs.to_path_buf(),
            models: runs.join("models"),
            episodes: 500,
            out: None,
            dry_run: true,
            no_train: false,
        }
    }

    #[test]
    fn run_names_are_those_of_fsrl_train() {
        let mut f = FileConfig::default();
        f.run.method = "sarl+foresight".into();
        f.run.setting = "env3-visible".into();
        f.run.seed = 2;
        let resolved = f.resolve(Vec::new()).unwrap();
        let name = run_name(Method::SarlForesight, set("env3-visible"), 2);
        assert_eq!(name, "sarl-foresight-env3-visible-s2");
        assert_eq!(resolved.default_run_dir(), Path::new("runs").join(&name));
        let layout = Layout {
            runs: "r".into(),
            models: "m".into(),
        };
        assert_eq!(
            layout.model(&name),
            Path::new("m/sarl-foresight-env3-visible-s2.fsrlm")
        );
        assert_eq!(
            layout.eval_dir(&name),
            Path::new("r/eval/sarl-foresight-env3-visible-s2")
        );
    }

    #[test]
    fn bad_names_are_refused_together_before_anything_starts() {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("c.toml");
        std::fs::write(&cfg, "[train]\ngamma = 1.5\n").unwrap();
        let mut a = args(&cfg, &tmp.path().join("runs"));
        a.methods = vec!["dqn".into(), "orca".into(), "sarl".into(), "sarl".into()];
        a.settings = vec!["env9-visible".into(), "env1-visible".into()];
        a.seeds = vec![0, 0];
        a.episodes = 0;
        let err = format!("{:#}", grid(&a).err().unwrap());
        for needle in [
            "7 problems",
            "unknown method `dqn`",
            "orca is not trained",
            "lists sarl twice",
            "unknown setting `env9-visible`",
            "--seeds lists 0 twice",
            "--episodes",
            "train.gamma",
        ] {
            assert!(err.contains(needle), "missing {needle:?} in\n{err}");
        }
        assert!(!tmp.path().join("runs").exists());

        a = args(&tmp.path().join("missing.toml"), tmp.path());
        let err = format!("{:#}", grid(&a).err().unwrap());
        assert!(err.contains("missing.toml"), "{err}");
    }

    /// Issue 44: a run `fsrl train` trained with the default replay ratio of distributed runs
    /// is not "trained with another [train]"; the same run is, for a grid of single-process
    /// runs or of the fixed schedule.
    #[test]
    fn a_default_distributed_run_is_trained_with_the_grids_own_train() {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("c.toml");
        std::fs::write(&cfg, "").unwrap();
        let mut a = args(&cfg, &tmp.path().join("runs"));
        a.settings = vec!["env1-invisible".into()];
        let layout = Layout {
            runs: a.runs.clone(),
            models: a.models.clone(),
        };
        // The run directory as `fsrl train` (distributed, no flags) leaves it.
        let dir = layout.run_dir(&run_name(Method::Sarl, set("env1-invisible"), 0));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        let mut file = FileConfig::load(Some(&cfg)).unwrap();
        file.run.method = "sarl".into();
        file.run.setting = "env1-invisible".into();
        let mut resolved = file.resolve(Vec::new()).unwrap();
        resolved.file.train.rl.replay_ratio = Some(policy::method::ReplayRatio::LOCAL_DEFAULT);
        resolved.file.train.select = policy::method::Select::DISTRIBUTED_DEFAULT;
        std::fs::write(
            dir.join("config.toml"),
            toml::to_string(&resolved.file).unwrap(),
        )
        .unwrap();
        let differs = |a: &ReproduceArgs| {
            let g = grid(a).unwrap();
            let cells = cells(&g.methods, &g.settings, &g.seeds);
            plan(&cells, &layout, &g.file.sim, &g.file.train, 500)[0].config_differs
        };
        assert!(!differs(&a), "a default distributed run");
        a.replay_ratio = Some(ReplayRatioArg(Some(
            policy::method::ReplayRatio::LOCAL_DEFAULT,
        )));
        assert!(!differs(&a), "--replay-ratio 4,20");
        a.replay_ratio = Some(ReplayRatioArg(None));
        assert!(differs(&a), "--replay-ratio fixed");
        a.replay_ratio = None;
        a.single_process = true;
        assert!(differs(&a), "--single-process");
        // Bounds in the file and single-process runs: refused with the grid's other problems.
        std::fs::write(&cfg, "[train.rl]\nreplay_ratio = { min = 2, max = 9 }\n").unwrap();
        let e = format!("{:#}", grid(&a).err().unwrap());
        assert!(e.contains("needs distributed runs"), "{e}");
    }

    #[test]
    fn the_plan_lists_every_run_and_the_estimate() {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("c.toml");
        std::fs::write(&cfg, "").unwrap();
        let mut a = args(&cfg, &tmp.path().join("runs"));
        a.methods = vec!["lstm-rl".into(), "fsrl".into()];
        a.settings = vec!["env1-invisible".into()];
        a.seeds = vec![0, 1];
        let g = grid(&a).unwrap();
        let layout = Layout {
            runs: a.runs.clone(),
            models: a.models.clone(),
        };
        let dir = layout.run_dir("fsrl-env1-invisible-s0");
        std::fs::create_dir_all(dir.join("checkpoints")).unwrap();
        std::fs::write(dir.join("checkpoints/latest.ckpt"), "x").unwrap();
        let p = plan(
            &cells(&g.methods, &g.settings, &g.seeds),
            &layout,
            &g.file.sim,
            &g.file.train,
            500,
        );
        let names: Vec<&str> = p.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "lstm-rl-env1-invisible-s0",
                "fsrl-env1-invisible-s0",
                "lstm-rl-env1-invisible-s1",
                "fsrl-env1-invisible-s1"
            ]
        );
        let text = describe(&p, false, &g.file.train, 500, false);
        assert!(
            text.contains("resume (0 RL ep. logged; from the last checkpoint)"),
            "{text}"
        );
        assert!(
            text.contains(
                "4 runs: 0 finished, 1 to resume, 3 to train; 4 to export, 4 to evaluate"
            ),
            "{text}"
        );
        let text = describe(&p, true, &g.file.train, 500, true);
        assert!(
            text.contains("(skipped: --no-train); 0 to export, 0 to evaluate; estimated 0s"),
            "{text}"
        );
    }
}
