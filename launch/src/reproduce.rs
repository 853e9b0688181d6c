//! `fsrl reproduce`: the paper's grid in one command. Trains methods × settings × seeds (each
//! run in its own setting, as the paper does), exports every finished run as a model file,
//! evaluates each model on the test seeds of its setting and ORCA on all six, and writes one
//! report beside the paper's numbers (`lab::compare`, in this process).
//!
//! Every step is a child process of the fsrl executable (`fsrl train`: a learner, actors and
//! an evaluator, or `fsrl train --single-process`; `fsrl export-model`, `fsrl eval`); this
//! module decides what to run from `lab::grid`'s plan. A run directory with `report.json` is
//! finished, one with `checkpoints/latest.ckpt` alone is resumed, any other is removed and
//! started again; a model at least as new as its run's `report.json` and an `eval.json` at
//! least as new as its model (same episodes, same setting) are kept. Running the same command
//! again therefore goes on where it stopped.
//!
//! Read top to bottom: [`grid`] checks the request, [`run`] plans the grid ([`plan_runs`]),
//! prints the plan, evaluates ORCA, then brings each run to completion ([`Steps::complete`]:
//! train, export, evaluate) and writes the report.

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
    rough_eval_s, rough_train_s, shard_of, Calibration, Cell, Layout, Planned, Shard, Training,
};
use policy::method::{Method, ReplayRatio, TrainConfig};
use sim::Setting;

use crate::config::{replay_ratio, select_rule, FileConfig, Mode};

/// What `fsrl reproduce` was asked for (its arguments, not yet checked).
#[derive(Debug, Clone)]
pub struct Request {
    /// Run configuration of every run [default: the built-in defaults].
    pub config: Option<PathBuf>,
    /// Train each run in one process (`fsrl train --single-process`).
    pub single_process: bool,
    /// Actor processes of each distributed run.
    pub actors: u32,
    /// `--replay-ratio` of each distributed run (`Some(None)`: `fixed`).
    pub replay_ratio: Option<Option<ReplayRatio>>,
    /// `--shard I/N` (else the scheduler's variables, else the whole grid).
    pub shard: Option<String>,
    pub methods: Vec<String>,
    /// Settings [default: all six].
    pub settings: Vec<String>,
    pub seeds: Vec<u64>,
    /// Run directories: RUNS/<method>-<setting>-s<seed>; evaluations in RUNS/eval/.
    pub runs: PathBuf,
    /// Model files: MODELS/<method>-<setting>-s<seed>.fsrlm.
    pub models: PathBuf,
    /// Test episodes of each evaluation.
    pub episodes: u32,
    /// Report directory [default: RUNS/report].
    pub out: Option<PathBuf>,
    /// Print the plan and the estimate; run nothing.
    pub dry_run: bool,
    /// Train nothing: export, evaluate and report the finished runs.
    pub no_train: bool,
}

// ---------------------------------------------------------------------------------------------
// The grid.

/// What the command line asks for, validated.
pub struct Grid {
    /// The config file, its `train.rl.replay_ratio` the one the runs are trained with (what
    /// `fsrl train` resolves for them: `--replay-ratio`, else the file's, else the default of
    /// distributed runs, by [`replay_ratio`]).
    pub file: FileConfig,
    pub mode: Mode,
    pub methods: Vec<Method>,
    pub settings: Vec<Setting>,
    pub seeds: Vec<u64>,
}

impl Grid {
    /// The `[train]` a run of `method` is trained with, as `fsrl train` resolves it (the
    /// method's preset, the snapshot rule of [`select_rule`]), so that a run on disk is
    /// compared with what it was trained with.
    pub fn train_of(&self, method: Method) -> TrainConfig {
        let file = &self.file;
        let mut t = method.train_config(&file.train);
        t.select = select_rule(method, &file.train, file.select_choice(), self.mode, None);
        t
    }
}

/// Reads the config and checks every name and number before anything starts, all problems
/// reported together.
pub fn grid(req: &Request) -> anyhow::Result<Grid> {
    let mut file = FileConfig::load(req.config.as_deref())?;
    let mut problems = Vec::new();
    if req.actors == 0 {
        problems.push("--actors must be at least 1".to_string());
    }
    let mode = if req.single_process {
        Mode::SingleProcess
    } else {
        Mode::Distributed
    };
    match replay_ratio(mode, req.replay_ratio, None, file.train.rl.replay_ratio) {
        Ok((r, _)) => file.train.rl.replay_ratio = r,
        Err(_) => {
            if let Some(Some(_)) = req.replay_ratio {
                problems.push("--replay-ratio MIN,MAX needs distributed runs; --single-process trains the fixed schedule".to_string());
            }
            if file.train.rl.replay_ratio.is_some() {
                problems.push("train.rl.replay_ratio (the adaptive mode) needs distributed runs; --single-process trains the fixed schedule: drop one of the two".to_string());
            }
        }
    }
    let methods = methods(&req.methods, &mut problems);
    let names: Vec<String> = if req.settings.is_empty() {
        Setting::ALL.iter().map(|s| s.name().to_string()).collect()
    } else {
        req.settings.clone()
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
    for (i, s) in req.seeds.iter().enumerate() {
        if req.seeds[..i].contains(s) {
            problems.push(format!("--seeds lists {s} twice"));
        }
    }
    if req.methods.is_empty() || req.seeds.is_empty() {
        problems.push("--methods and --seeds must name at least one each".into());
    }
    if req.episodes == 0 {
        problems.push("--episodes must be at least 1".into());
    }
    // The rest of the file (schedule, run id, ...), checked as `fsrl train` will check it.
    let mut probe = file.clone();
    probe.run.method = Method::Sarl.name().into();
    probe.run.setting = Setting::ALL[0].name().into();
    probe.train.select = select_rule(Method::Sarl, &file.train, file.select_choice(), mode, None);
    probe.train_select_given = true;
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
        mode,
        methods,
        settings,
        seeds: req.seeds.clone(),
    })
}

/// The methods to train, each once; ORCA is never trained.
fn methods(names: &[String], problems: &mut Vec<String>) -> Vec<Method> {
    let mut methods = Vec::new();
    for name in names {
        match name.parse::<Method>() {
            Ok(Method::Orca) => problems.push(
                "--methods: orca is not trained (its row is always in the report)".to_string(),
            ),
            Ok(m) if methods.contains(&m) => problems.push(format!("--methods lists {m} twice")),
            Ok(m) => methods.push(m),
            Err(e) => problems.push(format!("--methods: {e}")),
        }
    }
    methods
}

// ---------------------------------------------------------------------------------------------
// The plan.

/// The grid's runs (this shard's, with `--shard` or a scheduler's task) and what each still
/// needs; refuses to train runs another shard is training.
fn plan_runs(
    req: &Request,
    grid: &Grid,
    layout: &Layout,
    shard: Option<Shard>,
) -> anyhow::Result<Vec<Planned>> {
    let cells = cells(&grid.methods, &grid.settings, &grid.seeds);
    let mut planned = plan(
        &cells,
        layout,
        &grid.file.sim,
        &|m| grid.train_of(m),
        req.episodes,
    );
    let Some(sh) = shard else {
        return Ok(planned);
    };
    planned = planned
        .into_iter()
        .enumerate()
        .filter(|(k, _)| sh.holds(*k))
        .map(|(_, p)| p)
        .collect();
    if !req.dry_run && !req.no_train {
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
    Ok(planned)
}

/// The plan's first line: the grid, where everything goes, and the shard.
fn header(
    req: &Request,
    grid: &Grid,
    layout: &Layout,
    runs: usize,
    shard: Option<Shard>,
) -> String {
    let header = format!(
        "fsrl reproduce: {} seeds × {} settings × {} methods = {} runs (seed-major, then setting, then method), config {}, runs in {}, models in {}, {} test episodes per evaluation\n",
        grid.seeds.len(),
        grid.settings.len(),
        grid.methods.len(),
        runs,
        req.config
            .as_ref()
            .map_or("(built-in defaults)".to_string(), |c| c.display().to_string()),
        layout.runs.display(),
        layout.models.display(),
        req.episodes
    );
    match shard {
        Some(sh) => format!(
            "{header}shard {}/{}: {} of the grid's runs (run k belongs to shard k mod {})\n",
            sh.index, sh.count, runs, sh.count
        ),
        None => header,
    }
}

/// Plans the grid, prints the plan, and (unless `dry_run`) runs it: ORCA's evaluation, each
/// run trained, exported and evaluated, and the report of them all.
pub fn run(req: Request) -> anyhow::Result<()> {
    let grid = grid(&req)?;
    let layout = Layout {
        runs: req.runs.clone(),
        models: req.models.clone(),
    };
    let shard = shard_of(req.shard.as_deref(), &|k| std::env::var(k).ok())
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let planned = plan_runs(&req, &grid, &layout, shard)?;
    let train = &grid.file.train;
    let orca_dir = layout.orca_eval_dir();
    let orca_current = eval_is_current(&orca_dir, &Setting::ALL, req.episodes, None);
    let table = describe(&planned, orca_current, train, req.episodes, req.no_train);
    let header = header(&req, &grid, &layout, planned.len(), shard);
    if req.dry_run {
        print!("{header}{table}");
        return Ok(());
    }
    eprint!("{header}{table}");

    let mut steps = Steps {
        runner: Runner::new()?,
        cal: Calibration::default(),
        // `--config FILE` for every child, or nothing: the children's defaults are this one's.
        config: match &req.config {
            Some(c) => os(&[&"--config", c]),
            None => Vec::new(),
        },
        req: &req,
        layout: &layout,
        train,
    };
    // ORCA's row: evaluated by the whole grid or by shard 0.
    if !orca_current && shard.is_none_or(|s| s.index == 0) {
        steps.orca(&orca_dir)?;
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
        if !steps.complete(&tag, p)? {
            continue;
        }
        sources.push(p.eval_dir.join("eval.json"));
        complete += 1;
        eprintln!(
            "{tag}: done in {}; {complete}/{n} runs complete, grid ETA {}",
            duration_text(start.elapsed().as_secs_f64()),
            duration_text(
                steps
                    .cal
                    .eta_s(&planned[i + 1..], train, req.episodes, req.no_train)
            )
        );
    }
    if let Some(sh) = shard {
        eprintln!(
            "shard {}/{} done: {complete} of its {n} runs complete; when every shard is done, `fsrl reproduce --no-train` with the same grid, --runs and --models writes the report",
            sh.index, sh.count
        );
        return Ok(());
    }
    report(&req, &sources)
}

/// The report of every evaluated run and ORCA (`lab::compare`).
fn report(req: &Request, sources: &[PathBuf]) -> anyhow::Result<()> {
    let report_dir = req.out.clone().unwrap_or_else(|| req.runs.join("report"));
    eprintln!(
        "report of {} evaluated runs and ORCA → {}",
        sources.len() - 1,
        report_dir.display()
    );
    let c = lab::compare::compare(sources, &[])?;
    println!("{}", c.markdown);
    c.write_to(&report_dir)?;
    println!(
        "written: {}/compare.md, compare.csv, compare.json",
        report_dir.display()
    );
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The steps of a run.

/// The steps of the grid's runs, as child processes, and their timing.
struct Steps<'a> {
    runner: Runner,
    cal: Calibration,
    config: Vec<OsString>,
    req: &'a Request,
    layout: &'a Layout,
    train: &'a TrainConfig,
}

impl Steps<'_> {
    /// ORCA on the six settings.
    fn orca(&mut self, orca_dir: &Path) -> anyhow::Result<()> {
        eprintln!("[orca] evaluating ORCA on the six settings ...");
        let episodes = self.req.episodes.to_string();
        self.runner.step(
            "[orca]",
            "evaluating ORCA",
            orca_dir,
            &[
                os(&[&"eval", &"--orca", &"--episodes", &episodes]),
                self.config.clone(),
                os(&[&"--out", &orca_dir]),
            ]
            .concat(),
        )
    }

    /// Trains (unless finished), exports and evaluates the run `p`; `false` when its training
    /// is not finished and `--no-train` skips it.
    fn complete(&mut self, tag: &str, p: &Planned) -> anyhow::Result<bool> {
        let state = Training::of(&p.run_dir);
        if state != Training::Finished {
            if self.req.no_train {
                eprintln!("{tag}: training not finished; skipped (--no-train)");
                return Ok(false);
            }
            self.train_run(tag, p, state)?;
        }
        if !model_is_current(&p.model, &p.run_dir) {
            self.export(tag, p)?;
        }
        if !eval_is_current(
            &p.eval_dir,
            &[p.cell.setting],
            self.req.episodes,
            Some(&p.model),
        ) {
            self.evaluate(tag, p)?;
        }
        Ok(true)
    }

    /// `fsrl train` of the run, new, restarted or resumed.
    fn train_run(&mut self, tag: &str, p: &Planned, state: Training) -> anyhow::Result<()> {
        let Cell {
            method,
            setting,
            seed,
        } = p.cell;
        if state == Training::Restart {
            eprintln!(
                "{tag}: {} holds neither report.json nor a checkpoint (stopped during imitation); removing it",
                p.run_dir.display()
            );
            std::fs::remove_dir_all(&p.run_dir)
                .with_context(|| format!("cannot remove {}", p.run_dir.display()))?;
        }
        let rough = rough_train_s(method, self.train, state);
        eprintln!(
            "{tag}: training, {}, about {} ...",
            state.text(),
            duration_text(rough * self.cal.train_factor(method))
        );
        let seed_text = seed.to_string();
        let mode = if self.req.single_process {
            os(&[&"--single-process"])
        } else {
            let mut m = os(&[&"--actors", &self.req.actors.to_string()]);
            if let Some(r) = self.req.replay_ratio {
                let r = r.map_or("fixed".to_string(), |r| format!("{},{}", r.min, r.max));
                m.extend(os(&[&"--replay-ratio", &r]));
            }
            m
        };
        let mut a = [os(&[&"train"]), mode, self.config.clone()].concat();
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
        self.runner.step(tag, "training", &p.run_dir, &a)?;
        if Training::of(&p.run_dir) != Training::Finished {
            bail!(
                "{tag}: fsrl train exited without writing {}",
                p.run_dir.join("report.json").display()
            );
        }
        self.cal
            .record_train(method, t0.elapsed().as_secs_f64(), rough);
        Ok(())
    }

    /// `fsrl export-model` of the finished run.
    fn export(&mut self, tag: &str, p: &Planned) -> anyhow::Result<()> {
        let models = &self.layout.models;
        eprintln!("{tag}: exporting {} ...", p.model.display());
        std::fs::create_dir_all(models)
            .with_context(|| format!("cannot create {}", models.display()))?;
        self.runner.step(
            tag,
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
        Ok(())
    }

    /// `fsrl eval` of the run's model on the test seeds of its setting.
    fn evaluate(&mut self, tag: &str, p: &Planned) -> anyhow::Result<()> {
        let (method, setting) = (p.cell.method, p.cell.setting);
        let episodes = self.req.episodes.to_string();
        eprintln!("{tag}: evaluating on {episodes} test episodes of {setting} ...");
        let t0 = Instant::now();
        self.runner.step(
            tag,
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
        self.cal.record_eval(
            method,
            t0.elapsed().as_secs_f64(),
            rough_eval_s(method, self.req.episodes),
        );
        Ok(())
    }
}

fn os(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<OsString> {
    args.iter().map(|a| a.as_ref().to_os_string()).collect()
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RunSection;
    use lab::run::run_name;

    fn set(name: &str) -> Setting {
        name.parse().unwrap()
    }

    /// A dry run of SARL on env1-invisible, seed 0, with the config file `config`, in `runs`.
    fn args(config: &Path, runs: &Path) -> Request {
        Request {
            config: Some(config.to_path_buf()),
            single_process: false,
            actors: 2,
            replay_ratio: None,
            shard: None,
            methods: vec!["sarl".into()],
            settings: vec!["env1-invisible".into()],
            seeds: vec![0],
            runs: runs.to_path_buf(),
            models: runs.join("models"),
            episodes: 500,
            out: None,
            dry_run: true,
            no_train: false,
        }
    }

    /// [`args`] with the config file `dir/c.toml` (its path returned too), which holds `config`,
    /// and the runs in `dir/runs`.
    fn request(dir: &Path, config: &str, runs: &str) -> (PathBuf, Request) {
        let cfg = dir.join("c.toml");
        std::fs::write(&cfg, config).unwrap();
        let a = args(&cfg, &dir.join(runs));
        (cfg, a)
    }

    fn layout_of(a: &Request) -> Layout {
        Layout {
            runs: a.runs.clone(),
            models: a.models.clone(),
        }
    }

    /// A finished run of `method` on env1-invisible, seed 0, in `layout`, as `fsrl train` with
    /// the config file `cfg` leaves it (its `report.json`): its directory and its configuration,
    /// resolved (for [`write_config`]).
    fn finished_run(
        layout: &Layout,
        cfg: &Path,
        method: Method,
    ) -> (PathBuf, crate::config::Resolved) {
        let dir = layout.run_dir(&run_name(method, set("env1-invisible"), 0));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("report.json"), "{}").unwrap();
        let mut file = FileConfig::load(Some(cfg)).unwrap();
        file.run.method = method.name().into();
        file.run.setting = "env1-invisible".into();
        (dir, file.resolve(Vec::new()).unwrap())
    }

    /// The run's `config.toml`, as `fsrl train` writes it.
    fn write_config(dir: &Path, r: &crate::config::Resolved) {
        std::fs::write(dir.join("config.toml"), toml::to_string(&r.file).unwrap()).unwrap()
    }

    /// Asserts that the grid of `a` is refused, its error naming each of `needles`.
    fn assert_refused(a: &Request, needles: &[&str]) {
        let err = format!("{:#}", grid(a).err().unwrap());
        for needle in needles {
            assert!(err.contains(needle), "missing {needle:?} in\n{err}");
        }
    }

    /// Whether the plan of `a`'s grid says its first run was trained with another `[train]`.
    fn config_differs(a: &Request, layout: &Layout) -> bool {
        let g = grid(a).unwrap();
        let cells = cells(&g.methods, &g.settings, &g.seeds);
        plan(&cells, layout, &g.file.sim, &|m| g.train_of(m), 500)[0].config_differs
    }

    #[test]
    fn run_names_are_those_of_fsrl_train() {
        let run = RunSection {
            method: "sarl+foresight".into(),
            setting: "env3-visible".into(),
            seed: 2,
            ..RunSection::default()
        };
        let f = FileConfig {
            run,
            ..FileConfig::default()
        };
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
        let (_, mut a) = request(tmp.path(), "[train]\ngamma = 1.5\n", "runs");
        a.methods = vec!["dqn".into(), "orca".into(), "sarl".into(), "sarl".into()];
        a.settings = vec!["env9-visible".into(), "env1-visible".into()];
        a.seeds = vec![0, 0];
        a.episodes = 0;
        assert_refused(
            &a,
            &[
                "7 problems",
                "unknown method `dqn`",
                "orca is not trained",
                "lists sarl twice",
                "unknown setting `env9-visible`",
                "--seeds lists 0 twice",
                "--episodes",
                "train.gamma",
            ],
        );
        assert!(!tmp.path().join("runs").exists());

        a = args(&tmp.path().join("missing.toml"), tmp.path());
        assert_refused(&a, &["missing.toml"]);
    }

    /// Issue 44: a run `fsrl train` trained with the default replay ratio of distributed runs
    /// is not "trained with another [train]"; the same run is, for a grid of single-process
    /// runs or of the fixed schedule.
    #[test]
    fn a_default_distributed_run_is_trained_with_the_grids_own_train() {
        let tmp = tempfile::tempdir().unwrap();
        let (cfg, mut a) = request(tmp.path(), "", "runs");
        let layout = layout_of(&a);
        // The run directory as `fsrl train` (distributed, no flags) leaves it.
        let (dir, mut resolved) = finished_run(&layout, &cfg, Method::Sarl);
        resolved.file.train.rl.replay_ratio = Some(policy::method::ReplayRatio::LOCAL_DEFAULT);
        resolved.file.train.select = policy::method::Select::DISTRIBUTED_DEFAULT;
        write_config(&dir, &resolved);
        let differs = |a: &Request| config_differs(a, &layout);
        assert!(!differs(&a), "a default distributed run");
        a.replay_ratio = Some(Some(ReplayRatio::LOCAL_DEFAULT));
        assert!(!differs(&a), "--replay-ratio 4,20");
        a.replay_ratio = Some(None);
        assert!(differs(&a), "--replay-ratio fixed");
        a.replay_ratio = None;
        a.single_process = true;
        assert!(differs(&a), "--single-process");
        // Bounds in the file and single-process runs: refused with the grid's other problems.
        std::fs::write(&cfg, "[train.rl]\nreplay_ratio = { min = 2, max = 9 }\n").unwrap();
        assert_refused(&a, &["needs distributed runs"]);
    }

    #[test]
    fn the_plan_lists_every_run_and_the_estimate() {
        let tmp = tempfile::tempdir().unwrap();
        let (_, mut a) = request(tmp.path(), "", "runs");
        a.methods = vec!["lstm-rl".into(), "fsrl".into()];
        a.seeds = vec![0, 1];
        let g = grid(&a).unwrap();
        let layout = layout_of(&a);
        let dir = layout.run_dir("fsrl-env1-invisible-s0");
        std::fs::create_dir_all(dir.join("checkpoints")).unwrap();
        std::fs::write(dir.join("checkpoints/latest.ckpt"), "x").unwrap();
        let p = plan(
            &cells(&g.methods, &g.settings, &g.seeds),
            &layout,
            &g.file.sim,
            &|m| g.train_of(m),
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
        // (ORCA's evaluation current, --no-train): what the description says.
        let cases: [(bool, bool, &[&str]); 2] = [
            (
                false,
                false,
                &[
                    "resume (0 RL ep. logged; from the last checkpoint)",
                    "4 runs: 0 finished, 1 to resume, 3 to train; 4 to export, 4 to evaluate",
                ],
            ),
            (
                true,
                true,
                &["(skipped: --no-train); 0 to export, 0 to evaluate; estimated 0s"],
            ),
        ];
        for (orca_current, no_train, needles) in cases {
            let text = describe(&p, orca_current, &g.file.train, 500, no_train);
            for needle in needles {
                assert!(text.contains(needle), "{needle:?} in\n{text}");
            }
        }
    }

    /// Issue 52: an `fsrl-plan` run of a grid whose config chooses its own `[train] select` is
    /// trained with that choice, not the method's preset; the plan must not call it "trained
    /// with another [train]" (it did, in both modes), and a run with another choice still is.
    #[test]
    fn an_fsrl_plan_run_with_the_files_own_select_is_trained_with_the_grids_train() {
        let tmp = tempfile::tempdir().unwrap();
        for single_process in [false, true] {
            let runs = format!("runs-{single_process}");
            let (cfg, mut a) = request(tmp.path(), "[train]\nselect = \"low-disc\"\n", &runs);
            a.methods = vec!["fsrl-plan".into()];
            a.single_process = single_process;
            let layout = layout_of(&a);
            // The run directory as `fsrl train --method fsrl-plan --config c.toml` leaves it.
            let (dir, mut resolved) = finished_run(&layout, &cfg, Method::FsrlPlan);
            if !single_process {
                resolved.for_processes(&dir, false, None, true).unwrap();
            }
            assert_eq!(resolved.file.train.select, policy::method::Select::LowDisc);
            write_config(&dir, &resolved);
            assert!(
                !config_differs(&a, &layout),
                "single process: {single_process}"
            );
            resolved.file.train.select = policy::method::Select::BestReturn;
            write_config(&dir, &resolved);
            assert!(
                config_differs(&a, &layout),
                "another choice, single process: {single_process}"
            );
        }
    }
}
