//! A distributed run on one machine (`fsrl train`'s default mode): a learner, N actors and an
//! evaluator as child processes of the fsrl executable, on the iceoryx2 data plane (or zenoh)
//! with zenoh on loopback for metrics and liveliness. No router, no set-up. Progress comes from
//! the live metrics; a stop (the caller's flag, set on Ctrl-C) stops every child cleanly (the
//! learner checkpoints), and the same run with `resume` goes on. Every process's metrics go to
//! `processes.jsonl`, the learning curve into `metrics.jsonl`, the timing into `run.json`.
//! [`run`] reads top to bottom, one named phase after another.

use std::collections::BTreeMap;
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

/// zenoh's usual port when it is free, else a free loopback port below the kernel's ephemeral
/// range; never one this process already handed to another run. Two runs launched at the same
/// moment from one process (tests do) both found 7447 free before either learner had bound
/// it; and a port from `bind(0)` is an ephemeral one, which any outgoing connection may take
/// as its source port before the learner binds it.
fn learner_port() -> anyhow::Result<u16> {
    use std::sync::Mutex;
    static HANDED_OUT: Mutex<Vec<u16>> = Mutex::new(Vec::new());
    let mut handed = HANDED_OUT.lock().unwrap_or_else(|e| e.into_inner());
    let low: u32 = 10_000;
    let high = std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<u32>().ok())
        .unwrap_or(32_768)
        .clamp(low + 1000, 65_535);
    let offset = std::process::id().wrapping_mul(7919) % (high - low);
    let candidates = std::iter::once(7447)
        .chain((0..high - low).map(|i| (low + (offset + i) % (high - low)) as u16));
    for port in candidates {
        if !handed.contains(&port) && TcpListener::bind(("127.0.0.1", port)).is_ok() {
            handed.push(port);
            return Ok(port);
        }
    }
    bail!("no free TCP port on 127.0.0.1 for the learner (tried 7447 and {low}..{high})")
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

/// The learner's final figures in place of its newest live metrics, for the summary and
/// `run.json`: read from the run directory, where the learner writes them durably before it
/// exits (`learner::record`), never from whichever of its best-effort metrics messages arrived
/// (all of a short run's can be lost, and its last rounds of updates come after its last episode).
fn use_final_figures(
    out: &Path,
    last: &mut std::collections::BTreeMap<String, proto::Metrics>,
) -> anyhow::Result<()> {
    learner::record::use_final_figures(out, last)
        .context("the learner's final figures (the realised replay ratio) are missing")
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
    /// Serve the run's live page on this port of 127.0.0.1 (`fsrl dashboard`, a child process;
    /// 0: any free port, the one printed).
    pub dashboard: Option<u16>,
    /// Keep the run's TensorBoard files (`tb/`) in step with its logs and live metrics.
    pub tensorboard: bool,
}

/// Runs the processes to the end of the schedule (or until `stop` is set), then the final
/// evaluation of the run's policy; prints progress on stderr and the summary on stdout.
///
/// The phases, in order: [`prepare`] (the run's directory, endpoints and `config.toml`),
/// [`start_processes`] (learner, actors, evaluator) and [`start_page`] (the live page), [`watch`]
/// (the live metrics until the learner exits), [`wait_for_the_others`], [`keep_the_logs`], and
/// for a finished run [`final_report`] (the final evaluation, `run.json`, the summary).
pub fn run(launch: Launch, stop: &AtomicBool) -> anyhow::Result<()> {
    let started = Instant::now();
    let mut run = prepare(launch)?;
    let mut children = start_processes(&run)?;
    let mut page = start_page(&run)?;
    let mut watched = watch(&run, &mut children, &mut page, stop)?;
    let exit = watched.learner_exit;
    // The learner is done: actors and the evaluator finish on their own (the evaluator after the
    // final evaluation); after a stop, they are told to stop too.
    let interrupted = stop.load(Ordering::SeqCst) || !exit.success();
    if interrupted {
        children.signal(libc::SIGINT);
    }
    let mut failed = Vec::new();
    if !exit.success() {
        failed.push(format!("learner ({exit})"));
    }
    wait_for_the_others(&mut children, interrupted, stop, &mut failed)?;
    keep_the_logs(&run, &mut watched);
    let logs = run.out.join("logs");
    if !exit.success() {
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
            run.out.display()
        );
        return Ok(());
    }
    final_report(&mut run, watched, started)
}

/// A launched run: what [`prepare`] decided.
struct Prepared {
    launch: Launch,
    out: PathBuf,
    logs: PathBuf,
    /// The learner's zenoh endpoint; every other process connects to it.
    learner_ep: String,
    /// The run's `config.toml`, as the processes' `--config`.
    cfg_arg: String,
    /// The live page's port (the real one, when 0 was asked for).
    page_port: Option<u16>,
}

/// The run's directory and config: loopback endpoints, the learner listening on a free port,
/// the live page's port taken, the run's `config.toml` written.
fn prepare(mut launch: Launch) -> anyhow::Result<Prepared> {
    if launch.actors == 0 {
        bail!("a distributed run needs at least one actor");
    }
    let out = launch.out.clone();
    run_checkpoint(&out, launch.resume)?;
    let page_port = launch.dashboard.map(page_port).transpose()?;
    let logs = out.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;
    let port = learner_port()?;
    let learner_ep = format!("tcp/127.0.0.1:{port}");
    let f = &mut launch.resolved.file;
    f.run.id = run_id(&out);
    f.transport.data_plane = launch.data_plane;
    f.transport.zenoh.multicast_scouting = false;
    f.transport.zenoh.connect = Vec::new();
    f.transport.zenoh.listen = vec!["tcp/127.0.0.1:0".into()];
    f.learner.run_dir = Some(out.clone());
    f.evaluator.out_dir = Some(out.clone());
    f.evaluator.threads = 1;
    // The launcher evaluates the run's chosen policy itself at the end, as `--single-process`.
    f.evaluator.final_report = false;
    if let Some(n) = launch.eval_episodes {
        f.evaluator.episodes_per_setting = n;
    }
    let cfg_path = out.join("config.toml");
    std::fs::write(&cfg_path, toml::to_string(&launch.resolved.file)?)
        .with_context(|| format!("cannot write {}", cfg_path.display()))?;
    Ok(Prepared {
        launch,
        logs,
        learner_ep,
        cfg_arg: cfg_path.to_string_lossy().to_string(),
        page_port,
        out,
    })
}

/// The run id: the run directory's name, with any character a key expression cannot hold as
/// `_`.
fn run_id(out: &Path) -> String {
    out.file_name()
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
        .unwrap_or_else(|| "local".to_string())
}

/// The live page's port: `port` bound here first, so that a port in use is an error the user
/// sees before anything starts (the page's own process would only write it to its log), and
/// so that 0 becomes the free port the page will serve on, the one printed.
fn page_port(port: u16) -> anyhow::Result<u16> {
    let l = TcpListener::bind(("127.0.0.1", port)).with_context(|| {
        format!("--dashboard {port}: cannot serve the live page on 127.0.0.1:{port}")
    })?;
    Ok(l.local_addr()?.port())
}

/// The learner (listening on the known port), the actors and the evaluator.
fn start_processes(run: &Prepared) -> anyhow::Result<Children> {
    let (exe, logs, ep, cfg) = (&run.launch.exe, &run.logs, &run.learner_ep, &run.cfg_arg);
    let mut children = Children { list: Vec::new() };
    let learner_args = vec![
        "learner".to_string(),
        "--config".into(),
        cfg.clone(),
        "--listen".into(),
        ep.clone(),
    ];
    children.list.push((
        "learner".into(),
        spawn(exe, "learner", &learner_args, logs)?,
    ));
    for id in 0..run.launch.actors {
        let a = vec![
            "actor".to_string(),
            "--config".into(),
            cfg.clone(),
            "--id".into(),
            id.to_string(),
            "--connect".into(),
            ep.clone(),
        ];
        children.list.push((
            format!("actor-{id}"),
            spawn(exe, &format!("actor-{id}"), &a, logs)?,
        ));
    }
    if run.launch.evaluator {
        let e = vec![
            "evaluator".to_string(),
            "--config".into(),
            cfg.clone(),
            "--every".into(),
            "0".into(),
            "--connect".into(),
            ep.clone(),
        ];
        children
            .list
            .push(("evaluator".into(), spawn(exe, "evaluator", &e, logs)?));
    }
    let resolved = &run.launch.resolved;
    eprintln!(
        "training {} on {} in {} with {} actor process(es) over {} (learner at {ep}); logs in {}",
        resolved.method,
        resolved.setting,
        run.out.display(),
        run.launch.actors,
        plane_name(run.launch.data_plane),
        logs.display()
    );
    eprintln!(
        "live metrics from another terminal: fsrl watch --connect {ep} --run {}",
        resolved.file.run.id
    );
    Ok(children)
}

/// The live page: its own process (killed with the others at the end), reading the run's
/// metrics as `fsrl dashboard` does anywhere, on the port [`prepare`] took.
fn start_page(run: &Prepared) -> anyhow::Result<Page> {
    let mut page = Page {
        children: Children { list: Vec::new() },
        log: run.logs.join("dashboard.log"),
        said: false,
    };
    if let Some(port) = run.page_port {
        let d = vec![
            "dashboard".to_string(),
            "--connect".into(),
            run.learner_ep.clone(),
            "--run".into(),
            run.launch.resolved.file.run.id.clone(),
            "--port".into(),
            port.to_string(),
        ];
        let child = spawn(&run.launch.exe, "dashboard", &d, &run.logs)?;
        page.children.list.push(("dashboard".into(), child));
        eprintln!("live page: http://127.0.0.1:{port}/");
    }
    Ok(page)
}

/// The live page's process, watched: if it ends before the run does (it could not serve its
/// port, or failed), the user is told, once.
struct Page {
    children: Children,
    log: PathBuf,
    said: bool,
}

impl Page {
    /// Whether the page's process ended; says so (with its log's last line) the first time.
    fn check(&mut self, bar: &ProgressBar) {
        let Some((_, child)) = self.children.list.first_mut() else {
            return;
        };
        if self.said {
            return;
        }
        if let Ok(Some(status)) = child.try_wait() {
            self.said = true;
            let text = std::fs::read_to_string(&self.log).unwrap_or_default();
            let last = text
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            let text = format!(
                "warning: the live page stopped ({status}): {last} (see {})",
                self.log.display()
            );
            if bar.is_hidden() {
                eprintln!("{text}");
            } else {
                bar.println(text);
            }
        }
    }
}

/// What [`watch`] saw: how the learner ended, each process's newest metrics, when the warm
/// start ended, and the files it keeps.
struct Watched {
    learner_exit: std::process::ExitStatus,
    /// The newest metrics of each process.
    last_values: BTreeMap<String, proto::Metrics>,
    /// When the learner's warm start ended (its clock).
    warm_start_s: Option<f64>,
    board: Option<tboard::Keeper>,
    /// Where `validation.jsonl` ended before this invocation.
    validation_start: u64,
}

/// Every process's live metrics (one line each in `processes.jsonl`; the learner writes the
/// training log, metrics.jsonl, itself), the progress bar and the TensorBoard files, until the
/// learner exits (stopping every child when `stop` is set); then the metrics still in flight.
fn watch(
    run: &Prepared,
    children: &mut Children,
    page: &mut Page,
    stop: &AtomicBool,
) -> anyhow::Result<Watched> {
    let resolved = &run.launch.resolved;
    // Watch the run's metrics like any other tool would.
    let mut tcfg = resolved
        .file
        .transport
        .for_sender(&resolved.file.run.id, SenderId::new(Role::Monitor, 0))?;
    tcfg.data_plane = DataPlane::Zenoh;
    tcfg.zenoh.connect = vec![run.learner_ep.clone()];
    let monitor = Transport::open(tcfg)?;
    let metrics = monitor.subscriber(&keys::all_metrics(monitor.run()))?;
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(run.out.join("processes.jsonl"))
        .context("cannot open processes.jsonl")?;
    // The evaluator appends the learning curve to validation.jsonl; what this invocation adds
    // is copied into metrics.jsonl at the end, once the learner has stopped writing it.
    let validation_start =
        std::fs::metadata(run.out.join("validation.jsonl")).map_or(0, |m| m.len());
    // TensorBoard files in out/tb/: the logs as they grow, the learner's live-only values.
    let board = run
        .launch
        .tensorboard
        .then(|| tboard::Keeper::open(&run.out, tboard::Mode::Distributed));
    let mut progress = Progress::new(resolved.file.train.rl.episodes);
    let mut w = Watched {
        learner_exit: std::process::ExitStatus::default(),
        last_values: BTreeMap::new(),
        warm_start_s: None,
        board,
        validation_start,
    };
    w.learner_exit = loop {
        if stop.load(Ordering::SeqCst) {
            children.signal(libc::SIGINT);
        }
        let (_, learner) = &mut children.list[0];
        if let Some(status) = learner.try_wait()? {
            break status;
        }
        page.check(&progress.bar);
        if let Some(b) = &mut w.board {
            b.tick();
        }
        if let Some(msg) = metrics.recv_timeout(Duration::from_millis(200))? {
            w.record(&mut log, &msg);
            progress.show(&msg, &mut w.warm_start_s);
        }
    };
    progress.bar.finish_and_clear();
    // Metrics still queued or in flight when the learner exited (under load its last messages,
    // or all of a short run's, can be): take them before the summary reads each process's
    // last, so that run.json always has the learner's figures. Until 100 ms pass without one,
    // at most 2 s.
    let drain_until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < drain_until {
        let Some(msg) = metrics.recv_timeout(Duration::from_millis(100))? else {
            break;
        };
        w.record(&mut log, &msg);
    }
    Ok(w)
}

impl Watched {
    /// One metrics message: its line in `processes.jsonl`, the TensorBoard files, the newest
    /// of its sender.
    fn record(&mut self, log: &mut File, msg: &proto::Message<proto::Metrics>) {
        let sender = msg.header.sender.to_string();
        let line = serde_json::json!({ "sender": sender, "wall_s": msg.body.wall_time_s, "env_steps": msg.body.env_steps, "episodes": msg.body.episodes, "values": msg.body.values});
        let _ = writeln!(log, "{line}");
        if let Some(b) = &mut self.board {
            b.live(msg.header.sender, &msg.body);
        }
        self.last_values.insert(sender, msg.body.clone());
    }
}

/// The progress bar of a distributed run, from the live metrics (plain lines every 10 s when
/// stderr is not a terminal).
struct Progress {
    bar: ProgressBar,
    total: u64,
    last_plain: Instant,
}

impl Progress {
    fn new(total: u64) -> Self {
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr_with_hz(4));
        bar.set_style(
            ProgressStyle::with_template(
                "{prefix:>9} [{elapsed_precise}] {bar:30} {pos}/{len} (ETA {eta}) {msg}",
            )
            .expect("template"),
        );
        bar.set_prefix("starting");
        Self {
            bar,
            total,
            last_plain: Instant::now(),
        }
    }

    /// A message on the bar: an evaluator's validation point, or the learner's phase
    /// (demonstrations, imitation, RL) and figures; notes when the warm start ended.
    fn show(&mut self, msg: &proto::Message<proto::Metrics>, warm_start_s: &mut Option<f64>) {
        let bar = &self.bar;
        if msg.header.sender.role == Role::Evaluator {
            // A point of the learning curve; it reaches metrics.jsonl from the evaluator's
            // validation.jsonl when the run ends (this live copy is best effort).
            if let Some(line) = validation_line(&msg.body) {
                bar.println(format!(
                    "validation after {} RL episodes: success {:.2}, collision {:.2}, Disc. {:.3}",
                    line["episode"],
                    line["success_rate"].as_f64().unwrap_or(f64::NAN),
                    line["collision_rate"].as_f64().unwrap_or(f64::NAN),
                    line["discomfort"].as_f64().unwrap_or(f64::NAN)
                ));
            }
            return;
        }
        if msg.header.sender.role != Role::Learner {
            return;
        }
        let v = &msg.body.values;
        let get = |k: &str| v.get(k).copied().unwrap_or(0.0);
        if warm_start_s.is_none() && get("imitation_done") > 0.5 {
            *warm_start_s = Some(msg.body.wall_time_s);
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
        if bar.is_hidden() && self.last_plain.elapsed() >= Duration::from_secs(10) {
            self.last_plain = Instant::now();
            eprintln!(
                "{} {}/{} {}",
                bar.prefix(),
                bar.position(),
                self.total,
                bar.message()
            );
        }
    }
}

/// Waits for the actors and the evaluator. One that started after a short run's learner had
/// already finished waits for a learner that never comes: once an actor could have left (a
/// finished run's actors leave at once) or the evaluator finished a last validation, it is told
/// to stop. What failed is added to `failed`.
fn wait_for_the_others(
    children: &mut Children,
    interrupted: bool,
    stop: &AtomicBool,
    failed: &mut Vec<String>,
) -> anyhow::Result<()> {
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
    Ok(())
}

/// The learning curve this invocation added (`validation.jsonl`) into `metrics.jsonl`, and the
/// TensorBoard files finished.
fn keep_the_logs(run: &Prepared, w: &mut Watched) {
    let validation_path = run.out.join("validation.jsonl");
    let copied = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(run.out.join("metrics.jsonl"))
        .context("cannot open metrics.jsonl")
        .and_then(|mut m| copy_validation(&validation_path, w.validation_start, &mut m));
    if let Err(e) = copied {
        eprintln!("warning: the learning curve did not reach metrics.jsonl: {e:#}");
    }
    if let Some(b) = &mut w.board {
        b.finish();
    }
}

/// A finished run: the final evaluation of its policy, `run.json` (its timing, transport and
/// schedule, the learner's final counters), and the summary (stdout, and `report.md`).
fn final_report(run: &mut Prepared, mut w: Watched, started: Instant) -> anyhow::Result<()> {
    let out = &run.out;
    let launch = &run.launch;
    let rl_end_s = started.elapsed().as_secs_f64();
    let final_start = Instant::now();
    final_evaluation(
        out,
        &launch.resolved.spec(),
        &lab::policy_choice::run_policy(out, None)?,
    )?;
    let mut timing = RunTiming::read(out, "distributed");
    timing.set("actors", launch.actors);
    timing.set("transport", plane_name(launch.data_plane));
    // The schedule of updates: the adaptive bounds, or the fixed count per episode.
    let rl = &launch.resolved.file.train.rl;
    timing.set(
        "replay_ratio",
        match rl.replay_ratio {
            Some(r) => serde_json::json!({ "min": r.min, "max": r.max }),
            None => serde_json::json!(format!("fixed {}", rl.batches_per_episode)),
        },
    );
    let warm = w.warm_start_s.unwrap_or(0.0);
    timing.add_s("warm_start_s", warm);
    timing.add_s("rl_s", (rl_end_s - warm).max(0.0));
    timing.add_s("final_evaluation_s", final_start.elapsed().as_secs_f64());
    timing.add_s("total_s", started.elapsed().as_secs_f64());
    use_final_figures(out, &mut w.last_values)?;
    let mut summary = distributed_summary(&w.last_values, &mut timing);
    let train = &launch.resolved.file.train;
    if train.select == policy::method::Select::RevalidatedReturn {
        // Which snapshots were re-validated, what they scored and which is the policy (the
        // final evaluation's choice: every candidate is in revalidation.jsonl by now).
        let chosen = lab::policy_choice::chosen_snapshot(
            out,
            train.select,
            train.rl.epsilon_decay_episodes,
            &lab::revalidation::Plan::of(train),
            &mut |p, _, _, _| {
                anyhow::bail!(
                    "{} was not re-validated by the final evaluation",
                    p.display()
                )
            },
        )
        .ok()
        .flatten()
        .map(|(_, path)| path);
        let (lines, revalidation_s) = lab::revalidation::summary(out, chosen.as_deref());
        summary += &lines;
        timing.set("revalidation_s", revalidation_s);
    }
    timing.write(out)?;
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

    /// Two runs launched at once from one process never get the same learner port, and none
    /// is an ephemeral port (the kernel's `bind(0)` range).
    #[test]
    fn runs_launched_together_get_distinct_learner_ports_below_the_ephemeral_range() {
        let low = std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
            .ok()
            .and_then(|s| s.split_whitespace().next()?.parse::<u16>().ok())
            .unwrap_or(32_768);
        let ports: Vec<u16> = (0..3).map(|_| learner_port().unwrap()).collect();
        assert!(
            ports[0] != ports[1] && ports[1] != ports[2] && ports[0] != ports[2],
            "{ports:?}"
        );
        for p in ports {
            assert!(p < low, "{p} is an ephemeral port (range from {low})");
        }
    }

    /// Issue 52: the learner's figures of `run.json` (the realised replay ratio) are its final
    /// figures from the run directory, whatever live metrics arrived: none at all (they travel
    /// best effort; the intermittent `cli_train` failure) or a stale message. Without them the
    /// run's record is incomplete: an error, not a silent gap.
    #[test]
    fn the_learner_figures_come_from_the_run_directory() {
        let dir = tempfile::tempdir().unwrap();
        let mut figures = proto::Metrics::default();
        figures.values.insert("updates_per_episode".into(), 3.5);
        learner::record::write(dir.path(), &figures).unwrap();
        let mut none_arrived = std::collections::BTreeMap::new();
        use_final_figures(dir.path(), &mut none_arrived).unwrap();
        assert_eq!(none_arrived["learner-0"].values["updates_per_episode"], 3.5);
        let mut stale = proto::Metrics::default();
        stale.values.insert("updates_per_episode".into(), 1.5);
        let mut last = std::collections::BTreeMap::from([("learner-0".to_string(), stale)]);
        use_final_figures(dir.path(), &mut last).unwrap();
        assert_eq!(last["learner-0"].values["updates_per_episode"], 3.5);
        std::fs::remove_file(learner::record::path(dir.path())).unwrap();
        assert!(use_final_figures(dir.path(), &mut last).is_err());
    }
}
